use datasets::inject::{FaultSpec, Injection};
use datasets::sim::{MemorySink, SimConfig, run};
use datasets::sorting::{SortingConfig, SortingLine, SynthesisedControl, plant};
use diagnoser::{MS, SECOND};
#[test]
fn dbg() {
    let plant = plant();
    let spec: FaultSpec = "F2@600s".parse().unwrap();
    let _ = Injection::resolve(&spec, &plant).unwrap(); let faults = vec![];
    let mut line = SortingLine::new(SortingConfig::default());
    let ids = line.ids(); let mut ctl = AlwaysFeed(SynthesisedControl::new(ids), ids);
    let cfg = SimConfig { duration: 900 * SECOND, scan_period: 10 * MS, seed: 7, faults };
    let mut sink = MemorySink::default();
    let r = run(&mut line, &mut ctl, &cfg, &mut sink, |_| {}).unwrap();
    println!("{:?}", r.counters); for d in r.damage.iter().take(8) { println!("{d:?}"); }
    for e in sink.events.iter().take(0) { println!("{} {} {}", e.t/MS, plant.signals.name(e.signal), e.value as u8); }
}

struct AlwaysFeed(SynthesisedControl, datasets::sorting::SortingIds);
impl datasets::sim::Controller for AlwaysFeed {
    fn scan(&mut self, t: diagnoser::Time, io: &mut [bool]) {
        self.0.scan(t, io);
        io[self.1.a[0]] = true;
        io[self.1.a[1]] = true;
    }
}
