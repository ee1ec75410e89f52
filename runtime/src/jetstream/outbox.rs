//! What the monitor has to publish and the broker has not yet acknowledged:
//! a queue in memory, spilling to a file of its own when the broker is away,
//! bounded in bytes. Order is kept: once anything waits on disk, every newer
//! message goes behind it there, and the disk is read back before memory is
//! used again.
//!
//! ```
//! use runtime::jetstream::outbox::{Message, Outbox};
//!
//! let dir = tempfile::tempdir().unwrap();
//! let mut outbox = Outbox::new(dir.path().join("spool"), 2, 1 << 20);
//! for seq in 0..5 {
//!     outbox.push(Message { seq, subject: "gardefou.events.line".into(), payload: vec![1, 2] }).unwrap();
//! }
//! let mut sent = Vec::new();
//! while let Some(m) = outbox.front().unwrap() {
//!     sent.push(m.seq);
//!     outbox.pop();
//! }
//! assert_eq!(sent, [0, 1, 2, 3, 4]);
//! ```

use std::collections::VecDeque;
use std::fs::{File, OpenOptions};
use std::io::{self, BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::PathBuf;

/// One message to publish.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    /// Its number in the monitor's run, from 0: with the run's name, the
    /// JetStream message id, so that a message sent twice is stored once.
    pub seq: u64,
    /// The subject.
    pub subject: String,
    /// The payload.
    pub payload: Vec<u8>,
}

impl Message {
    /// Bytes it takes on disk.
    fn size(&self) -> u64 {
        (4 + self.subject.len() + 8 + 4 + self.payload.len()) as u64
    }
}

/// Why a message was not taken.
#[derive(Debug)]
pub enum Refused {
    /// The outbox holds its bound of bytes already.
    Full,
    /// The spool file failed.
    Io(io::Error),
}

/// The queue of messages not yet acknowledged.
#[derive(Debug)]
pub struct Outbox {
    memory: VecDeque<Message>,
    max_memory: usize,
    path: PathBuf,
    spool: Option<Spool>,
    max_bytes: u64,
    /// Bytes held, in memory and on disk.
    held: u64,
}

/// The spool file: written at its end, read from `read_at`.
#[derive(Debug)]
struct Spool {
    writer: BufWriter<File>,
    reader: BufReader<File>,
    /// Messages written and not yet read back.
    waiting: usize,
}

impl Outbox {
    /// An empty outbox keeping up to `max_memory` messages in memory, then
    /// spilling to the file `path` (made when first needed), up to
    /// `max_bytes` in all.
    pub fn new(path: PathBuf, max_memory: usize, max_bytes: u64) -> Outbox {
        Outbox {
            memory: VecDeque::new(),
            max_memory: max_memory.max(1),
            path,
            spool: None,
            max_bytes,
            held: 0,
        }
    }

    /// Messages held.
    pub fn len(&self) -> usize {
        self.memory.len() + self.spool.as_ref().map_or(0, |s| s.waiting)
    }

    /// Whether nothing is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        self.held
    }

    /// Takes a message, behind every other.
    pub fn push(&mut self, m: Message) -> Result<(), Refused> {
        let size = m.size();
        if self.held + size > self.max_bytes {
            return Err(Refused::Full);
        }
        let spilling = self.spool.as_ref().is_some_and(|s| s.waiting > 0);
        if !spilling && self.memory.len() < self.max_memory {
            self.memory.push_back(m);
        } else {
            self.spool()?.append(&m).map_err(Refused::Io)?;
        }
        self.held += size;
        Ok(())
    }

    /// The oldest message, read back from disk when memory has none.
    pub fn front(&mut self) -> io::Result<Option<&Message>> {
        if self.memory.is_empty() {
            self.refill()?;
        }
        Ok(self.memory.front())
    }

    /// Drops the oldest message (acknowledged).
    pub fn pop(&mut self) {
        if let Some(m) = self.memory.pop_front() {
            self.held -= m.size();
        }
    }

    fn spool(&mut self) -> Result<&mut Spool, Refused> {
        if self.spool.is_none() {
            self.spool = Some(Spool::create(&self.path).map_err(Refused::Io)?);
        }
        Ok(self.spool.as_mut().expect("just made"))
    }

    /// Moves up to `max_memory` messages from disk to memory; empties the
    /// file once it is all read.
    fn refill(&mut self) -> io::Result<()> {
        let Some(spool) = self.spool.as_mut() else {
            return Ok(());
        };
        spool.writer.flush()?;
        while spool.waiting > 0 && self.memory.len() < self.max_memory {
            self.memory.push_back(spool.read()?);
            spool.waiting -= 1;
        }
        if spool.waiting == 0 {
            spool.clear()?;
        }
        Ok(())
    }
}

impl Drop for Outbox {
    fn drop(&mut self) {
        if self.spool.take().is_some() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

impl Spool {
    fn create(path: &PathBuf) -> io::Result<Spool> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        let writer = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)?;
        // Opened twice, not cloned: a clone shares the file position, and
        // writing at the end would move where the reading goes on.
        let reader = File::open(path)?;
        Ok(Spool {
            writer: BufWriter::new(writer),
            reader: BufReader::new(reader),
            waiting: 0,
        })
    }

    fn append(&mut self, m: &Message) -> io::Result<()> {
        let w = &mut self.writer;
        w.write_all(&(m.subject.len() as u32).to_le_bytes())?;
        w.write_all(m.subject.as_bytes())?;
        w.write_all(&m.seq.to_le_bytes())?;
        w.write_all(&(m.payload.len() as u32).to_le_bytes())?;
        w.write_all(&m.payload)?;
        self.waiting += 1;
        Ok(())
    }

    fn read(&mut self) -> io::Result<Message> {
        let r = &mut self.reader;
        let mut n4 = [0u8; 4];
        let mut n8 = [0u8; 8];
        r.read_exact(&mut n4)?;
        let mut subject = vec![0u8; u32::from_le_bytes(n4) as usize];
        r.read_exact(&mut subject)?;
        r.read_exact(&mut n8)?;
        r.read_exact(&mut n4)?;
        let mut payload = vec![0u8; u32::from_le_bytes(n4) as usize];
        r.read_exact(&mut payload)?;
        let subject = String::from_utf8(subject)
            .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
        Ok(Message {
            seq: u64::from_le_bytes(n8),
            subject,
            payload,
        })
    }

    /// Everything read back: the file starts again empty.
    fn clear(&mut self) -> io::Result<()> {
        self.writer.flush()?;
        let file = self.writer.get_mut();
        file.set_len(0)?;
        file.seek(SeekFrom::Start(0))?;
        self.reader.seek(SeekFrom::Start(0))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn message(seq: u64, len: usize) -> Message {
        Message {
            seq,
            subject: format!("gardefou.events.p{}", seq % 3),
            payload: vec![seq as u8; len],
        }
    }

    #[test]
    fn a_full_outbox_refuses_and_takes_again_once_drained() {
        let dir = tempfile::tempdir().expect("dir");
        let one = message(0, 10).size();
        let mut o = Outbox::new(dir.path().join("spool"), 1, 3 * one);
        for seq in 0..3 {
            o.push(message(seq, 10)).expect("room");
        }
        assert!(matches!(o.push(message(3, 10)), Err(Refused::Full)));
        assert_eq!(o.front().expect("reads").map(|m| m.seq), Some(0));
        o.pop();
        o.push(message(3, 10)).expect("room again");
        assert_eq!(o.len(), 3);
        assert_eq!(o.bytes(), 3 * one);
    }

    proptest! {
        /// Any interleaving of pushes and acknowledgements, with a memory
        /// of any size: the messages come out in the order pushed, each
        /// once, whole; the bytes held are those not yet acknowledged.
        #[test]
        fn messages_come_out_in_order(
            ops in proptest::collection::vec((any::<bool>(), 0usize..300), 1..200),
            max_memory in 1usize..8,
        ) {
            let dir = tempfile::tempdir().expect("dir");
            let mut o = Outbox::new(dir.path().join("spool"), max_memory, u64::MAX);
            let (mut pushed, mut out) = (0u64, Vec::new());
            let mut expected = std::collections::VecDeque::new();
            for (push, len) in ops {
                if push {
                    let m = message(pushed, len);
                    expected.push_back(m.clone());
                    o.push(m).expect("unbounded");
                    pushed += 1;
                } else if let Some(m) = o.front().expect("reads").cloned() {
                    prop_assert_eq!(Some(&m), expected.front());
                    expected.pop_front();
                    out.push(m.seq);
                    o.pop();
                }
                prop_assert_eq!(o.len(), expected.len());
                prop_assert_eq!(o.bytes(), expected.iter().map(Message::size).sum::<u64>());
            }
            while let Some(m) = o.front().expect("reads").cloned() {
                prop_assert_eq!(Some(&m), expected.front());
                expected.pop_front();
                out.push(m.seq);
                o.pop();
            }
            prop_assert_eq!(out, (0..pushed).collect::<Vec<_>>());
        }
    }
}
