//! The flags of the coupling: what the diagnosers tell the safety filter.
//!
//! A flag belongs to a partition of faults (SPEC §2: one per component, e.g.
//! `C4`). `def_<partition>` says that a fault of the partition is certain; the
//! filter then reads the partition's sensor through its temporal estimate.
//! `suspect_<partition>` says that a fault of it is among the live candidates.
//! Flags are named so, as PLC variables, in `plant.toml` expressions, the
//! Structured Text, the verdict lines and the Modbus map; this type is the one
//! place that spells those names.
//!
//! ```
//! use vocabulary::{Flag, FlagKind};
//!
//! let flag = Flag::def("C4");
//! assert_eq!(flag.to_string(), "def_C4");
//! assert_eq!(Flag::parse("suspect_C4"), Some(Flag::suspect("C4")));
//! assert_eq!(Flag::parse("C4"), None);
//! assert_eq!(flag.kind, FlagKind::Def);
//! ```

use std::fmt;

/// What a flag says of its partition.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FlagKind {
    /// A fault of the partition is certain (`def_`); never lowered.
    Def,
    /// A fault of the partition is among the candidates (`suspect_`).
    Suspect,
}

impl FlagKind {
    /// The prefix of the flag's name.
    pub fn prefix(self) -> &'static str {
        match self {
            FlagKind::Def => "def_",
            FlagKind::Suspect => "suspect_",
        }
    }
}

/// A flag: its kind and its partition.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Flag {
    /// What it says.
    pub kind: FlagKind,
    /// The partition it is about.
    pub partition: String,
}

impl Flag {
    /// `def_<partition>`: a fault of the partition is certain.
    pub fn def(partition: impl Into<String>) -> Flag {
        Flag {
            kind: FlagKind::Def,
            partition: partition.into(),
        }
    }

    /// `suspect_<partition>`: a fault of the partition is a candidate.
    pub fn suspect(partition: impl Into<String>) -> Flag {
        Flag {
            kind: FlagKind::Suspect,
            partition: partition.into(),
        }
    }

    /// The flag named `name`, if it is one (`def_…` or `suspect_…`, with a
    /// partition after the prefix).
    pub fn parse(name: &str) -> Option<Flag> {
        [FlagKind::Def, FlagKind::Suspect]
            .into_iter()
            .find_map(|kind| {
                let partition = name.strip_prefix(kind.prefix())?;
                (!partition.is_empty()).then(|| Flag {
                    kind,
                    partition: partition.to_string(),
                })
            })
    }

    /// Whether `name` is this kind of flag of `partition`, without building it.
    pub fn names(kind: FlagKind, partition: &str, name: &str) -> bool {
        name.strip_prefix(kind.prefix()) == Some(partition)
    }
}

impl fmt::Display for Flag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}{}", self.kind.prefix(), self.partition)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn a_flag_reads_back_from_its_name(partition in "[A-Za-z0-9_]{1,12}", def in any::<bool>()) {
            let flag = if def { Flag::def(&partition) } else { Flag::suspect(&partition) };
            prop_assert_eq!(Flag::parse(&flag.to_string()), Some(flag.clone()));
            prop_assert!(Flag::names(flag.kind, &partition, &flag.to_string()));
        }
    }

    #[test]
    fn other_names_are_not_flags() {
        for name in ["C4", "def_", "suspect_", "DEF_C4", "defC4", ""] {
            assert_eq!(Flag::parse(name), None, "{name}");
        }
    }
}
