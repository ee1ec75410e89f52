//! Part suggestion (being written).
