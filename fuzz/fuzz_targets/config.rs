//! The pipeline.toml parser and validation on arbitrary text.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(cfg) = drbokeh::Config::parse(text) {
            let _ = cfg.validate();
        }
    }
});
