#![no_main]

// Parquet files only (its magic first); the form is detected from the schema.
libfuzzer_sys::fuzz_target!(|data: &[u8]| if data.starts_with(b"PAR1") {
    gardefou_fuzz::log(data, None)
});
