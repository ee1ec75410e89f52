//! Rows written plainly, read straight from their bytes.
//!
//! Most rows of a CSV log are written the way the writers write them: a
//! decimal time, signal names as the plant spells them, values `0` and `1`,
//! no quotes, no spaces. A form's reader recognises those from the line's
//! bytes ([`crate::Records::unread`]) with the pieces here, and reads
//! every other row field by field, with its rules and messages.

use vocabulary::{SignalId, SignalTable, Time};

/// The signal names a plain row may hold, looked up by their bytes: no
/// `String` and no SipHash per row.
pub(crate) struct SignalNames {
    /// Open addressing with linear probing: a power of two, at least twice as
    /// many slots as names, so that a probe ends at an empty slot.
    slots: Vec<Slot>,
    /// The odd multiplier of the hash, chosen so that names seldom share a
    /// slot: most lookups then probe once.
    multiplier: u64,
    /// The names, by signal index: the bytes past a slot's first eight.
    names: Vec<Box<[u8]>>,
}

/// A name's first eight bytes (little-endian, zero-padded), its length
/// (0 for an empty slot) and its signal.
#[derive(Debug, Clone, Copy, Default)]
struct Slot {
    head: u64,
    length: usize,
    id: u32,
}

/// How many multipliers and sizes [`SignalNames::new`] tries for a table
/// where no two names share a slot.
const ATTEMPTS: u64 = 64;

impl SignalNames {
    /// The names of `signals` that a field holds exactly as written: a name
    /// the reading of fields would trim or unquote (or that holds a comma or
    /// a line break) is left out, and its rows are read field by field.
    pub(crate) fn new(signals: &SignalTable) -> Self {
        let names: Vec<Box<[u8]>> = signals
            .iter()
            .map(|(_, s)| s.name.as_bytes().into())
            .collect();
        let smallest = (2 * names.len()).next_power_of_two().max(2);
        let mut table = SignalNames {
            slots: Vec::new(),
            multiplier: 0,
            names,
        };
        for attempt in 0..=ATTEMPTS {
            // Larger tables every sixteen attempts, up to eight times as large.
            let size = smallest << (attempt / 16).min(3);
            table.multiplier = 0x9e37_79b9_7f4a_7c15 ^ (attempt << 1);
            if table.fill(size) || attempt == ATTEMPTS {
                break;
            }
        }
        table
    }

    /// Fills a table of `size` slots with the plain names: whether no two
    /// share a slot.
    fn fill(&mut self, size: usize) -> bool {
        self.slots = vec![Slot::default(); size];
        let mut shared = false;
        for (index, name) in self.names.iter().enumerate() {
            if !as_written(name) {
                continue;
            }
            let head = head(name);
            let mut slot = self.slot(head, name.len());
            while self.slots[slot].length != 0 {
                shared = true;
                slot = (slot + 1) & (size - 1);
            }
            let (length, id) = (name.len(), index as u32);
            self.slots[slot] = Slot { head, length, id };
        }
        !shared
    }

    /// The signal named by the bytes of `row` up to its next comma, and the
    /// length of the name.
    #[inline(always)]
    pub(crate) fn prefix(&self, row: &[u8]) -> Option<(SignalId, usize)> {
        // Most names fit in a word: find the comma in the row's first eight
        // bytes at once.
        if let Some(word) = row.first_chunk::<8>() {
            let word = u64::from_le_bytes(*word);
            let commas = zero_bytes(word ^ 0x2c2c_2c2c_2c2c_2c2c);
            if commas != 0 {
                let length = (commas.trailing_zeros() / 8) as usize;
                let head = word & ((1u64 << (8 * length)) - 1);
                return Some((self.find(head, &row[..length])?, length));
            }
        }
        let length = find_byte(row, b',')?;
        let name = &row[..length];
        Some((self.find(head(name), name)?, length))
    }

    /// The signal named `name`, whose first eight bytes are `head`.
    #[inline(always)]
    fn find(&self, head: u64, name: &[u8]) -> Option<SignalId> {
        let mut slot = self.slot(head, name.len());
        loop {
            let candidate = self.slots[slot];
            if candidate.length == 0 {
                return None;
            }
            if candidate.head == head
                && candidate.length == name.len()
                && (name.len() <= 8 || self.names[candidate.id as usize][8..] == name[8..])
            {
                return Some(SignalId(candidate.id));
            }
            slot = (slot + 1) & (self.slots.len() - 1);
        }
    }

    /// Where the probe for a name starts.
    #[inline]
    fn slot(&self, head: u64, length: usize) -> usize {
        let hash = (head ^ length as u64).wrapping_mul(self.multiplier);
        (hash >> 32) as usize & (self.slots.len() - 1)
    }
}

/// A name's first eight bytes, little-endian, zero-padded.
fn head(name: &[u8]) -> u64 {
    let mut word = [0; 8];
    let n = name.len().min(8);
    word[..n].copy_from_slice(&name[..n]);
    u64::from_le_bytes(word)
}

/// Where the first `byte` of `bytes` is, looked for a word at a time: line
/// ends and commas in the reading of lines and fields.
#[inline]
pub(crate) fn find_byte(bytes: &[u8], byte: u8) -> Option<usize> {
    let pattern = u64::from(byte) * 0x0101_0101_0101_0101;
    let mut at = 0;
    while let Some(word) = bytes.get(at..).and_then(<[u8]>::first_chunk::<8>) {
        let found = zero_bytes(u64::from_le_bytes(*word) ^ pattern);
        if found != 0 {
            return Some(at + (found.trailing_zeros() / 8) as usize);
        }
        at += 8;
    }
    let rest = bytes.get(at..)?;
    rest.iter().position(|&b| b == byte).map(|p| at + p)
}

/// A word with the high bit set in the lowest zero byte of `word` (and
/// possibly in higher bytes, which the callers ignore); 0 if no byte is zero.
#[inline]
fn zero_bytes(word: u64) -> u64 {
    word.wrapping_sub(0x0101_0101_0101_0101) & !word & 0x8080_8080_8080_8080
}

/// Whether a field holding `name` reads as `name`: not empty, no comma, line
/// break or surrounding whitespace, not wrapped in quotes.
fn as_written(name: &[u8]) -> bool {
    let (Some(first), Some(last)) = (name.first(), name.last()) else {
        return false;
    };
    let quoted = name.len() >= 2 && *first == b'"' && *last == b'"';
    !quoted
        && !first.is_ascii_whitespace()
        && !last.is_ascii_whitespace()
        && !name.iter().any(|&b| matches!(b, b',' | b'\n' | b'\r'))
}

/// The most digits a plain time has: any 18 digits fit an `i64`, and longer
/// numbers are left to the reading of fields, which knows when they overflow.
const MOST_DIGITS: usize = 18;

/// The decimal number at the start of `row`, in `nanos` nanoseconds per unit,
/// and the number of its digits; `None` if there is none, or if it is too
/// long or too large to read here.
#[inline(always)]
pub(crate) fn time(row: &[u8], nanos: Time) -> Option<(Time, usize)> {
    let mut value: i64 = 0;
    let mut digits = 0;
    loop {
        let rest = &row[digits..];
        // Eight bytes at a time, then byte by byte at the end of what is read.
        let (n, part) = match rest.first_chunk::<8>() {
            Some(word) => {
                let word = u64::from_le_bytes(*word);
                let n = leading_digits(word);
                (
                    n,
                    if n == 0 {
                        0
                    } else {
                        eight_digits(word << (64 - 8 * n))
                    },
                )
            }
            None => {
                let n = rest.iter().take_while(|b| b.is_ascii_digit()).count();
                let part = rest[..n]
                    .iter()
                    .fold(0, |v, &b| v * 10 + i64::from(b - b'0'));
                (n, part)
            }
        };
        if digits + n > MOST_DIGITS {
            return None;
        }
        value = value * 10i64.pow(n as u32) + part;
        digits += n;
        if n < 8 {
            break;
        }
    }
    if digits == 0 {
        return None;
    }
    Some((value.checked_mul(nanos)?, digits))
}

/// How many of the eight bytes of `word` (little-endian: the first byte
/// lowest) are ASCII digits before the first that is not.
#[inline(always)]
fn leading_digits(word: u64) -> usize {
    const LOW: u64 = 0x0101_0101_0101_0101;
    // A digit is 0x30 to 0x39: high nibble 3, and still 3 once 6 is added.
    // A carry out of a byte only reaches bytes after one that is no digit.
    let high = (word & (0xF0 * LOW)) ^ (0x30 * LOW);
    let over = (word.wrapping_add(0x06 * LOW) & (0xF0 * LOW)) ^ (0x30 * LOW);
    ((high | over).trailing_zeros() / 8) as usize
}

/// The number the eight ASCII digits of `word` spell (first byte lowest, the
/// most significant digit), zero bytes counting as leading zeros.
#[inline(always)]
fn eight_digits(word: u64) -> i64 {
    // Neighbouring digits pair up, then pairs, then quads: one multiply each.
    let v = word & 0x0F0F_0F0F_0F0F_0F0F;
    let v = v.wrapping_mul(10 << 8 | 1) >> 8;
    let v = (v & 0x00FF_00FF_00FF_00FF).wrapping_mul(100 << 16 | 1) >> 16;
    let v = (v & 0x0000_FFFF_0000_FFFF).wrapping_mul(10_000 << 32 | 1) >> 32;
    v as i64
}

/// The value `0` or `1` at the start of `row`.
#[inline]
pub(crate) fn bit(row: &[u8]) -> Option<bool> {
    match row.first()? {
        b'0' => Some(false),
        b'1' => Some(true),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use vocabulary::{Signal, SignalKind};

    /// What [`time`] must give, digit by digit.
    fn time_by_digits(row: &[u8], nanos: Time) -> Option<(Time, usize)> {
        let digits = row.iter().take_while(|b| b.is_ascii_digit()).count();
        if digits == 0 || digits > MOST_DIGITS {
            return None;
        }
        let text = std::str::from_utf8(&row[..digits]).ok()?;
        Some((text.parse::<i64>().ok()?.checked_mul(nanos)?, digits))
    }

    proptest! {
        #[test]
        fn finds_bytes_as_one_by_one(
            bytes in proptest::collection::vec(prop_oneof![b'a'..=b'c', Just(b'\n')], 0..40),
            byte in prop_oneof![Just(b'\n'), Just(b'a')],
        ) {
            prop_assert_eq!(find_byte(&bytes, byte), bytes.iter().position(|&b| b == byte));
        }

        #[test]
        fn reads_times_as_digit_by_digit(
            row in proptest::collection::vec(
                prop_oneof![4 => b'0'..=b'9', 1 => any::<u8>()],
                0..30,
            ),
            nanos in prop_oneof![Just(1i64), Just(1_000), Just(1_000_000), Just(1_000_000_000)],
        ) {
            prop_assert_eq!(time(&row, nanos), time_by_digits(&row, nanos));
        }
    }

    /// The signal named `name`, if a plain row may name it: the same at the
    /// end of the bytes read and with a whole word after it.
    fn get(index: &SignalNames, name: &[u8]) -> Option<SignalId> {
        let short = index.prefix(&[name, b","].concat());
        let long = index.prefix(&[name, b",1\n0,C4,1\n"].concat());
        assert_eq!(short, long);
        let (id, length) = short?;
        assert_eq!(length, name.len());
        Some(id)
    }

    fn table(names: &[&str]) -> SignalTable {
        let mut table = SignalTable::new();
        for name in names {
            let signal = Signal {
                name: (*name).to_string(),
                kind: SignalKind::Sensor,
                description: String::new(),
            };
            table.push(signal);
        }
        table
    }

    #[test]
    fn finds_every_plain_name_and_no_other() {
        let mut names: Vec<String> = (0..40).map(|k| format!("C{k}")).collect();
        names.extend(
            [
                "abcdefg",
                "abcdefgh",
                "abcdefghi",
                "conveyor_1_running",
                "conveyor_2_running",
            ]
            .map(String::from),
        );
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let signals = table(&refs);
        let index = SignalNames::new(&signals);
        for (id, signal) in signals.iter() {
            assert_eq!(get(&index, signal.name.as_bytes()), Some(id));
        }
        assert_eq!(get(&index, b"C40"), None);
        assert_eq!(get(&index, b"abcdefgi"), None);
        assert_eq!(get(&index, b"conveyor_3_running"), None);
        assert_eq!(get(&index, b""), None);
        assert_eq!(
            index.prefix(b"C7,1\n"),
            Some((signals.id("C7").unwrap(), 2))
        );
        assert_eq!(index.prefix(b"C7"), None);
    }

    #[test]
    fn gives_names_like_a_plants_a_slot_each() {
        let names: Vec<String> = (0..11)
            .map(|k| format!("C{k}"))
            .chain((0..7).map(|k| format!("A{k}")))
            .collect();
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let index = SignalNames::new(&table(&refs));
        for (k, name) in names.iter().enumerate() {
            let name = name.as_bytes();
            let home = index.slots[index.slot(head(name), name.len())];
            assert_eq!(home.id as usize, k, "{:?} is not in its own slot", names[k]);
        }
    }

    #[test]
    fn leaves_out_names_a_field_would_not_hold_as_written() {
        let signals = table(&[" C4", "\"A4\"", "C5 ", "x\"y", "a\rb"]);
        let index = SignalNames::new(&signals);
        assert_eq!(get(&index, b" C4"), None);
        assert_eq!(get(&index, b"\"A4\""), None);
        assert_eq!(get(&index, b"C5 "), None);
        assert_eq!(get(&index, b"a\rb"), None);
        assert_eq!(get(&index, b"x\"y"), signals.id("x\"y"));
    }

    #[test]
    fn reads_plain_times_and_leaves_the_rest() {
        assert_eq!(time(b"120,C4", 1_000_000), Some((120_000_000, 3)));
        assert_eq!(time(b"007", 1), Some((7, 3)));
        assert_eq!(
            time(b"999999999999999999", 1),
            Some((999_999_999_999_999_999, 18))
        );
        assert_eq!(time(b"1000000000000000000", 1), None);
        assert_eq!(time(b"9999999999999", 1_000_000_000), None);
        assert_eq!(time(b"-5", 1), None);
        assert_eq!(time(b",", 1), None);
        assert_eq!(bit(b"1\n"), Some(true));
        assert_eq!(bit(b"t"), None);
    }
}
