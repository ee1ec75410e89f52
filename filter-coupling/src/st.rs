//! The safety filter as IEC 61131-3 Structured Text.
