//! The NPY decoder (depth maps, layers) on arbitrary bytes: no panic, no huge allocation.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = drbokeh::io::npy::decode_npy(data, 1 << 22);
});
