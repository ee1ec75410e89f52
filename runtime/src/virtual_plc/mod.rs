//! The virtual PLC of `gardefou simulate --serve-modbus`: the simulated sorting
//! line run in real time under safe control by constraints through the safety
//! filter, with its process image served over Modbus TCP.
//!
//! Clients read the sensors (discrete inputs) and the orders (coils), and write
//! the fault flags (coils) that the filter reads from the next scan on, and
//! the probe coils of a probing move (`monitor --probe`): while `<A>_PROBE` is
//! 1, the filter is asked for A at `<A>_PROBE_VALUE` ([`Filter::request`]) and
//! takes it in each scan where no safety constraint forbids it; the scan sets
//! `<A>_PROBE_REFUSED` where one did. The register map is the plant's
//! [`ModbusMap`]:
//!
//! - function 1 reads coils and function 2 discrete inputs;
//! - functions 5 and 15 write flag coils and the `_PROBE` and `_PROBE_VALUE`
//!   coils only: writing an actuator's coil, a `_PROBE_REFUSED` coil, or any
//!   address that holds none of those, gives the exception IllegalDataAddress
//!   and writes nothing;
//! - a read reaching past the highest mapped address of its table gives
//!   IllegalDataAddress; unmapped addresses below it read 0;
//! - a quantity of 0 or above the protocol's limit gives IllegalDataValue;
//! - every other function gives IllegalFunction.
//!
//! The scan loop runs on its own thread so that network traffic never delays
//! a scan; scans are due at absolute instants (origin + k · period / speed), so
//! a late scan does not shift the ones after it.

mod requests;

use std::future::{Ready, ready};
use std::io;
use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::mpsc::{self, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use datasets::sim::{Damage, SimConfig, Stepper};
use diagnoser::model::Model;
use diagnoser::plant::{ModbusMap, ModbusTable};
use diagnoser::{Failure, MS, Plant, Time};
use filter_coupling::filter::{Coupling, Filter, Request as FilterRequest};
use serde::Serialize;
use tokio::net::{TcpListener, TcpStream};
use tokio_modbus::server::Service;
use tokio_modbus::server::tcp::Server;
use tokio_modbus::{ExceptionCode, Request, Response};

use crate::closed_loop::{CoupledPlc, Rig, Watched};
/// Most coils or discrete inputs one read may ask for (Modbus application
/// protocol, functions 1 and 2).
const MAX_READ: u16 = 2000;
/// Most coils one write may carry (function 15).
const MAX_WRITE: u16 = 1968;

/// Settings of one virtual PLC run.
#[derive(Debug)]
pub struct VirtualPlc {
    /// Address to listen on, e.g. `127.0.0.1:5020` (port 0: any free port).
    pub addr: String,
    /// Simulated time per wall-clock time.
    pub speed: f64,
    /// The learned model: the sensors' temporal estimates.
    pub model: Model,
    /// How the filter uses the flags clients write.
    pub coupling: Coupling,
    /// Duration, scan period, seed and faults of the simulation.
    pub config: SimConfig,
}

/// What one address of a Modbus table holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cell {
    /// Nothing: reads 0, cannot be written.
    Hole,
    /// A sensor or actuator: read-only for clients.
    Signal,
    /// A flag: written by clients, read by the filter.
    Flag,
    /// `<A>_PROBE` or `<A>_PROBE_VALUE`: written by clients, read by the
    /// scan loop.
    Probe,
    /// `<A>_PROBE_REFUSED`: set by the scan loop, read-only for clients.
    ProbeRefused,
}

/// One Modbus bit table: a value and a use per address.
#[derive(Debug, Default)]
struct Table {
    values: Vec<bool>,
    cells: Vec<Cell>,
}

impl Table {
    fn put(&mut self, address: u16, cell: Cell) {
        let a = usize::from(address);
        if self.cells.len() <= a {
            self.cells.resize(a + 1, Cell::Hole);
            self.values.resize(a + 1, false);
        }
        self.cells[a] = cell;
    }

    /// The addresses `[address, address + quantity)`, if all are in the table.
    fn range(
        &self,
        address: u16,
        quantity: usize,
    ) -> Result<std::ops::Range<usize>, ExceptionCode> {
        let start = usize::from(address);
        let end = start + quantity;
        if end > self.values.len() {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        Ok(start..end)
    }

    fn read(&self, address: u16, quantity: u16) -> Result<Vec<bool>, ExceptionCode> {
        if quantity == 0 || quantity > MAX_READ {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let range = self.range(address, usize::from(quantity))?;
        Ok(self.values[range].to_vec())
    }

    /// Writes flags and probe coils; nothing is written unless every address
    /// holds one. True if a probe coil was written.
    fn write_flags(&mut self, address: u16, values: &[bool]) -> Result<bool, ExceptionCode> {
        let range = self.range(address, values.len())?;
        let cells = &self.cells[range.clone()];
        if cells
            .iter()
            .any(|&c| !matches!(c, Cell::Flag | Cell::Probe))
        {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let probe = cells.contains(&Cell::Probe);
        self.values[range].copy_from_slice(values);
        Ok(probe)
    }
}

/// The process image shared by the scan loop and the Modbus clients.
#[derive(Debug, Default)]
struct Image {
    inputs: Table,
    coils: Table,
    /// Client writes that reached a probe coil (for the summary: a monitor
    /// without `--probe` never writes one).
    probe_writes: u64,
}

impl Image {
    fn new(map: &ModbusMap) -> Image {
        let mut image = Image::default();
        for &(table, address) in &map.signals {
            image.table_mut(table).put(address, Cell::Signal);
        }
        for (_, address) in &map.flags {
            image.coils.put(*address, Cell::Flag);
        }
        for p in &map.probes {
            image.coils.put(p.probe, Cell::Probe);
            image.coils.put(p.value, Cell::Probe);
            image.coils.put(p.refused, Cell::ProbeRefused);
        }
        image
    }

    /// Writes client coils, counting the writes of probe coils.
    fn write_coils(&mut self, address: u16, values: &[bool]) -> Result<(), ExceptionCode> {
        let probe = self.coils.write_flags(address, values)?;
        self.probe_writes += u64::from(probe);
        Ok(())
    }

    fn table_mut(&mut self, table: ModbusTable) -> &mut Table {
        match table {
            ModbusTable::DiscreteInput => &mut self.inputs,
            ModbusTable::Coil => &mut self.coils,
        }
    }

    /// The answer to one client request.
    fn answer(&mut self, request: Request<'static>) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadCoils(address, quantity) => {
                self.coils.read(address, quantity).map(Response::ReadCoils)
            }
            Request::ReadDiscreteInputs(address, quantity) => self
                .inputs
                .read(address, quantity)
                .map(Response::ReadDiscreteInputs),
            Request::WriteSingleCoil(address, value) => self
                .write_coils(address, &[value])
                .map(|()| Response::WriteSingleCoil(address, value)),
            Request::WriteMultipleCoils(address, values) => {
                let quantity = u16::try_from(values.len())
                    .ok()
                    .filter(|&n| n > 0 && n <= MAX_WRITE)
                    .ok_or(ExceptionCode::IllegalDataValue)?;
                self.write_coils(address, &values)
                    .map(|()| Response::WriteMultipleCoils(address, quantity))
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// Locks the image. The lock is only held for plain reads and writes that
/// cannot panic half-way, so a poisoned image is still consistent.
fn lock(image: &Mutex<Image>) -> MutexGuard<'_, Image> {
    image.lock().unwrap_or_else(|e| e.into_inner())
}

/// The Modbus service of one client connection.
struct ImageService(Arc<Mutex<Image>>);

impl Service for ImageService {
    type Request = Request<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = Ready<Result<Response, ExceptionCode>>;

    fn call(&self, request: Request<'static>) -> Self::Future {
        ready(lock(&self.0).answer(request))
    }
}

/// Serves a process image of `map`'s cells, all reading 0, over Modbus TCP
/// on `listener` until dropped, as a virtual PLC serves its own (clients may
/// write only the flag coils), with no plant running behind it: the request
/// handling alone, for its fuzz target.
pub async fn serve_image(listener: TcpListener, map: &ModbusMap) {
    serve(listener, Arc::new(Mutex::new(Image::new(map)))).await;
}

/// Accepts clients until dropped; each client has its own task, so one that
/// sends garbage or goes away only ends its own connection.
async fn serve(listener: TcpListener, image: Arc<Mutex<Image>>) {
    let server = Server::new(listener);
    let on_connected = |stream: TcpStream, _peer: SocketAddr| {
        let service = ImageService(Arc::clone(&image));
        async move {
            // Requests and answers are a few bytes each: send them at once.
            let _ = stream.set_nodelay(true);
            io::Result::Ok(Some((service, requests::Checked::new(stream))))
        }
    };
    let on_error = |e: io::Error| eprintln!("virtual PLC: dropped a client: {e}");
    loop {
        // `serve` only returns when accepting fails (e.g. out of file
        // descriptors); wait a little and accept again.
        if let Err(e) = server.serve(&on_connected, on_error).await {
            eprintln!("virtual PLC: cannot accept clients: {e}");
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
}

/// What a virtual PLC run did.
#[derive(Debug)]
struct Summary {
    scans: u64,
    /// Simulated time of the last scan.
    end: Time,
    delivered: u64,
    /// Boxes delivered since the first flag was raised (all of them, if none).
    delivered_since_flag: u64,
    damage: Vec<Damage>,
    /// Flags in the order first seen raised, with the scan that first read them.
    flags: Vec<(String, Time)>,
    fallback_scans: u64,
    /// Client writes that reached a probe coil.
    probe_writes: u64,
    /// Probing moves asked for (an `_PROBE` coil read at 1, or a new value
    /// while it is).
    probe_requests: u64,
    /// Scans in which the filter refused a requested move.
    probe_refused_scans: u64,
    late_scans: u64,
    /// The latest a scan came, in simulated time: how far the plant fell
    /// behind real time at worst (a loaded machine).
    most_late: Time,
    interrupted: bool,
}

/// The flags the scan loop reads: name, coil and the value the filter has.
struct FlagCoil {
    name: String,
    coil: usize,
    applied: bool,
}

/// One actuator's probe coils as the scan loop reads and sets them.
struct ProbeCoilState {
    actuator: String,
    probe: usize,
    value: usize,
    refused: usize,
    /// What the filter has been asked for.
    requested: Option<bool>,
}

/// The probing moves clients ask for, and what the filter did with them.
struct Probes {
    coils: Vec<ProbeCoilState>,
    requests: u64,
    refused_scans: u64,
}

impl Probes {
    fn new(plant: &Plant, map: &ModbusMap) -> Probes {
        let coils = map
            .probes
            .iter()
            .map(|p| ProbeCoilState {
                actuator: plant.signals.name(p.actuator).to_string(),
                probe: usize::from(p.probe),
                value: usize::from(p.value),
                refused: usize::from(p.refused),
                requested: None,
            })
            .collect();
        Probes {
            coils,
            requests: 0,
            refused_scans: 0,
        }
    }

    /// Asks the filter for the moves the coils request now, from this scan
    /// on: `A` at `A_PROBE_VALUE` while `A_PROBE` is 1, and the control's
    /// order again once it is 0.
    fn read(&mut self, image: &Image, plc: &mut CoupledPlc) {
        let bit = |a: usize| image.coils.values.get(a).copied().unwrap_or(false);
        for p in &mut self.coils {
            let want = bit(p.probe).then(|| bit(p.value));
            if want != p.requested {
                // The filter keeps a request until told otherwise: asking
                // only on a change is asking in every scan.
                plc.filter_mut().request(&p.actuator, want);
                self.requests += u64::from(want.is_some());
                p.requested = want;
            }
        }
    }

    /// Sets each `A_PROBE_REFUSED` from what the scan just made of the
    /// requests.
    fn write(&mut self, image: &mut Image, plc: &CoupledPlc) {
        let mut any = false;
        for p in &self.coils {
            let refused = plc
                .last_requests()
                .iter()
                .any(|(a, r)| *a == p.actuator && matches!(r, FilterRequest::Refused(_)));
            any |= refused;
            if let Some(v) = image.coils.values.get_mut(p.refused) {
                *v = refused;
            }
        }
        self.refused_scans += u64::from(any);
    }
}

/// Runs the scans until the end of the run or a message on `stop`.
fn scan_loop(
    plant: &Plant,
    mut filter: Filter,
    config: &SimConfig,
    speed: f64,
    image: &Mutex<Image>,
    stop: &mpsc::Receiver<()>,
) -> Result<Summary, String> {
    let map = plant.modbus_map();
    let mut flags: Vec<FlagCoil> = map
        .flags
        .iter()
        .map(|(flag, coil)| FlagCoil {
            name: flag.to_string(),
            coil: usize::from(*coil),
            applied: false,
        })
        .collect();
    // All flags start lowered, as the coils do.
    for f in &flags {
        filter.set(&f.name, false);
    }
    let mut probes = Probes::new(plant, &map);
    let mut plc = CoupledPlc::new(filter, None, 0);
    let mut physics = Watched::new(Rig::Sorting, 0);
    let mut stepper = Stepper::new(plant, config);
    let period_s = config.scan_period.max(1) as f64 / 1e9 / speed;
    let period = Duration::try_from_secs_f64(period_s).unwrap_or(Duration::MAX);
    let mut raised: Vec<(String, Time)> = Vec::new();
    let mut late_scans = 0u64;
    let mut most_late = Duration::ZERO;
    let mut delivered_at_flag = 0u64;
    let mut interrupted = false;
    let mut end = 0;
    let origin = Instant::now();
    while let Some(t) = stepper.next_scan() {
        // Scan k is due at origin + k · period, computed afresh each time so that
        // rounding does not accumulate.
        let k = stepper.scans() as f64;
        let due = Duration::try_from_secs_f64(k * period_s)
            .ok()
            .and_then(|d| origin.checked_add(d))
            .unwrap_or(origin);
        let now = Instant::now();
        let stopped = if now < due {
            !matches!(stop.recv_timeout(due - now), Err(RecvTimeoutError::Timeout))
        } else {
            !matches!(stop.try_recv(), Err(TryRecvError::Empty))
        };
        if stopped {
            interrupted = true;
            break;
        }
        let late = Instant::now().saturating_duration_since(due);
        most_late = most_late.max(late);
        if late > period {
            late_scans += 1;
        }
        {
            let image = lock(image);
            for f in &mut flags {
                let value = image.coils.values.get(f.coil).copied().unwrap_or(false);
                if value != f.applied {
                    // A flag the filter does not read (coupling none) is still
                    // reported in the summary.
                    plc.filter_mut().set(&f.name, value);
                    f.applied = value;
                    if value && !raised.iter().any(|(n, _)| *n == f.name) {
                        if raised.is_empty() {
                            delivered_at_flag = physics.delivered();
                        }
                        raised.push((f.name.clone(), t));
                    }
                }
            }
            probes.read(&image, &mut plc);
        }
        let Some((t, values)) = stepper
            .step(&mut physics, &mut plc)
            .map_err(|e| format!("simulation failed: {e}"))?
        else {
            break;
        };
        end = t;
        {
            let mut image = lock(image);
            for (&(table, address), &value) in map.signals.iter().zip(values) {
                let table = image.table_mut(table);
                if let Some(v) = table.values.get_mut(usize::from(address)) {
                    *v = value;
                }
            }
            probes.write(&mut image, &plc);
        }
    }
    Ok(Summary {
        scans: stepper.scans(),
        end,
        delivered: physics.delivered(),
        delivered_since_flag: physics.delivered() - delivered_at_flag,
        damage: stepper.damage().to_vec(),
        flags: raised,
        fallback_scans: plc.fallback_scans(),
        late_scans,
        most_late: (most_late.as_secs_f64() * speed * 1e9) as Time,
        probe_writes: lock(image).probe_writes,
        probe_requests: probes.requests,
        probe_refused_scans: probes.refused_scans,
        interrupted,
    })
}

/// Runs the virtual PLC of `plant` (the sorting line) until the end of the run
/// or SIGINT/SIGTERM, then prints the summary: one JSON line on stdout, one
/// line for people on stderr.
pub fn run(plant: &Plant, plc: VirtualPlc) -> Result<(), Failure> {
    let addr = plc
        .addr
        .to_socket_addrs()
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| {
            Failure::BadInput(format!(
                "bad --serve-modbus '{}': expected HOST:PORT, e.g. 127.0.0.1:5020",
                plc.addr
            ))
        })?;
    let filter = Filter::new(plant, Some(&plc.model), plc.coupling).map_err(Failure::BadInput)?;
    let map = plant.modbus_map();
    let image = Arc::new(Mutex::new(Image::new(&map)));
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|e| Failure::Io(format!("cannot start the runtime: {e}")))?;
    let summary = runtime.block_on(async {
        let listener = TcpListener::bind(addr)
            .await
            .map_err(|e| Failure::Io(format!("cannot listen on {addr}: {e}")))?;
        let local = listener
            .local_addr()
            .map_err(|e| Failure::Io(format!("cannot listen on {addr}: {e}")))?;
        let mut stop = StopSignals::watch()?;
        eprintln!(
            "virtual PLC: serving Modbus TCP on {local} ({}, scan {} ms, speed {}, coupling {}; {})",
            plant.name,
            plc.config.scan_period as f64 / MS as f64,
            plc.speed,
            plc.coupling.name(),
            describe_map(plant, &map)
        );
        let server = tokio::spawn(serve(listener, Arc::clone(&image)));
        let (stop_tx, stop_rx) = mpsc::channel();
        let scan_image = Arc::clone(&image);
        let scan_plant = plant.clone();
        let config = plc.config.clone();
        let speed = plc.speed;
        let mut scans = tokio::task::spawn_blocking(move || {
            scan_loop(&scan_plant, filter, &config, speed, &scan_image, &stop_rx)
        });
        let done = tokio::select! {
            done = &mut scans => done,
            () = stop.recv() => {
                let _ = stop_tx.send(());
                scans.await
            }
        };
        server.abort();
        done.map_err(|e| Failure::Io(format!("the scan loop failed: {e}")))?
            .map_err(Failure::Io)
    })?;
    runtime.shutdown_timeout(Duration::from_secs(1));
    print_summary(&summary)
}

/// The register map in a few words, for the start line.
fn describe_map(plant: &Plant, map: &ModbusMap) -> String {
    let span = |table: ModbusTable, kind: diagnoser::SignalKind| {
        let addresses: Vec<u16> = plant
            .signals
            .iter()
            .zip(&map.signals)
            .filter(|((_, s), (t, _))| s.kind == kind && *t == table)
            .map(|(_, (_, a))| *a)
            .collect();
        match (addresses.iter().min(), addresses.iter().max()) {
            (Some(lo), Some(hi)) => format!("{lo}-{hi}"),
            _ => "none".to_string(),
        }
    };
    fn range(coils: impl Iterator<Item = u16> + Clone) -> String {
        match (coils.clone().min(), coils.max()) {
            (Some(lo), Some(hi)) => format!("{lo}-{hi}"),
            _ => "none".to_string(),
        }
    }
    let flags = range(map.flags.iter().map(|f| f.1));
    let probes = range(
        map.probes
            .iter()
            .flat_map(|p| [p.probe, p.value, p.refused]),
    );
    use diagnoser::SignalKind::{Actuator, Sensor};
    format!(
        "sensors: discrete inputs {}, actuators: read-only coils {}, flags: coils {flags}, probes: coils {probes}",
        span(ModbusTable::DiscreteInput, Sensor),
        span(ModbusTable::Coil, Actuator),
    )
}

fn print_summary(summary: &Summary) -> Result<(), Failure> {
    /// The JSON summary line, fields in this order.
    #[derive(Serialize)]
    struct Line<'a> {
        scans: u64,
        delivered: u64,
        delivered_since_flag: u64,
        damage: Vec<DamageLine<'a>>,
        flags: Vec<FlagLine<'a>>,
        fallback_scans: u64,
        probe_writes: u64,
        probe_requests: u64,
        probe_refused_scans: u64,
        late_scans: u64,
        most_late_ms: f64,
        interrupted: bool,
    }
    #[derive(Serialize)]
    struct DamageLine<'a> {
        t_ms: Time,
        kind: &'a str,
    }
    #[derive(Serialize)]
    struct FlagLine<'a> {
        flag: &'a str,
        t_ms: Time,
    }
    let line = Line {
        scans: summary.scans,
        delivered: summary.delivered,
        delivered_since_flag: summary.delivered_since_flag,
        damage: summary
            .damage
            .iter()
            .map(|d| DamageLine {
                t_ms: d.t / MS,
                kind: d.cause,
            })
            .collect(),
        flags: summary
            .flags
            .iter()
            .map(|(flag, t)| FlagLine { flag, t_ms: t / MS })
            .collect(),
        fallback_scans: summary.fallback_scans,
        probe_writes: summary.probe_writes,
        probe_requests: summary.probe_requests,
        probe_refused_scans: summary.probe_refused_scans,
        late_scans: summary.late_scans,
        most_late_ms: summary.most_late as f64 / 1e6,
        interrupted: summary.interrupted,
    };
    let json = serde_json::to_string(&line)
        .map_err(|e| Failure::Io(format!("cannot write the summary: {e}")))?;
    let flags: Vec<String> = summary
        .flags
        .iter()
        .map(|(f, t)| format!("{f} at {} s", *t as f64 / 1e9))
        .collect();
    eprintln!(
        "virtual PLC: {} after {} scans ({} s simulated): {} boxes delivered, {} damage event(s), flags raised: {}, {} fallback scans, {} probing move(s) requested ({} scans refused), {} late scans",
        if summary.interrupted {
            "interrupted"
        } else {
            "done"
        },
        summary.scans,
        summary.end as f64 / 1e9,
        summary.delivered,
        summary.damage.len(),
        if flags.is_empty() {
            "none".to_string()
        } else {
            flags.join(", ")
        },
        summary.fallback_scans,
        summary.probe_requests,
        summary.probe_refused_scans,
        summary.late_scans
    );
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{json}")
        .and_then(|()| out.flush())
        .map_err(Failure::output)
}

/// SIGINT and SIGTERM, watched from before the start line is printed so that
/// a client reacting to that line can already stop the run cleanly.
#[cfg(unix)]
struct StopSignals {
    interrupt: tokio::signal::unix::Signal,
    terminate: tokio::signal::unix::Signal,
}

#[cfg(unix)]
impl StopSignals {
    fn watch() -> Result<StopSignals, Failure> {
        use tokio::signal::unix::{SignalKind, signal};
        let watch = |kind: SignalKind, name: &str| {
            signal(kind).map_err(|e| Failure::Io(format!("cannot watch {name}: {e}")))
        };
        Ok(StopSignals {
            interrupt: watch(SignalKind::interrupt(), "SIGINT")?,
            terminate: watch(SignalKind::terminate(), "SIGTERM")?,
        })
    }

    /// Returns at the first of the two signals.
    async fn recv(&mut self) {
        tokio::select! {
            Some(()) = self.interrupt.recv() => {}
            Some(()) = self.terminate.recv() => {}
            else => std::future::pending::<()>().await,
        }
    }
}

/// Ctrl-C, where there are no Unix signals.
#[cfg(not(unix))]
struct StopSignals;

#[cfg(not(unix))]
impl StopSignals {
    fn watch() -> Result<StopSignals, Failure> {
        Ok(StopSignals)
    }

    async fn recv(&mut self) {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image() -> Image {
        Image::new(&datasets::sorting::plant().modbus_map())
    }

    #[test]
    fn reads_past_the_last_address_are_refused_and_holes_read_zero() {
        let mut image = image();
        // Sorting line: 11 sensors, 7 actuators, flags from coil 100.
        assert_eq!(image.inputs.values.len(), 11);
        assert_eq!(image.coils.cells[7], Cell::Hole);
        assert_eq!(
            image.answer(Request::ReadDiscreteInputs(0, 12)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            image.answer(Request::ReadCoils(5, 4)),
            Ok(Response::ReadCoils(vec![false; 4]))
        );
        assert_eq!(
            image.answer(Request::ReadCoils(0, 0)),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            image.answer(Request::ReadHoldingRegisters(0, 1)),
            Err(ExceptionCode::IllegalFunction)
        );
    }

    #[test]
    fn only_flag_coils_can_be_written() {
        let mut image = image();
        assert_eq!(
            image.answer(Request::WriteSingleCoil(100, true)),
            Ok(Response::WriteSingleCoil(100, true))
        );
        assert!(image.coils.values[100]);
        assert_eq!(
            image.answer(Request::WriteSingleCoil(4, true)),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert!(!image.coils.values[4]);
        // One actuator among flags: nothing is written.
        assert_eq!(
            image.answer(Request::WriteMultipleCoils(6, vec![true; 96].into())),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            image.answer(Request::WriteMultipleCoils(101, vec![true, true].into())),
            Ok(Response::WriteMultipleCoils(101, 2))
        );
        assert_eq!(&image.coils.values[100..104], &[true, true, true, false]);
        assert_eq!(image.probe_writes, 0);
    }

    #[test]
    fn clients_write_probe_coils_but_not_the_refusals() {
        let mut image = image();
        // A4 is the fifth actuator: A4_PROBE 212, A4_PROBE_VALUE 213,
        // A4_PROBE_REFUSED 214.
        assert_eq!(
            image.answer(Request::WriteMultipleCoils(212, vec![true, true].into())),
            Ok(Response::WriteMultipleCoils(212, 2))
        );
        assert_eq!(&image.coils.values[212..214], &[true, true]);
        assert_eq!(image.probe_writes, 1);
        for refused in [214, 202] {
            assert_eq!(
                image.answer(Request::WriteSingleCoil(refused, false)),
                Err(ExceptionCode::IllegalDataAddress)
            );
        }
        assert_eq!(
            image.answer(Request::ReadCoils(200, 21)),
            Ok(Response::ReadCoils(
                (200..221).map(|a| a == 212 || a == 213).collect()
            ))
        );
        assert_eq!(image.probe_writes, 1);
    }
}
