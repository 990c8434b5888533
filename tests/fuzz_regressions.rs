//! Inputs found by the fuzzers (fuzz/): every loader must refuse them with an error (no panic,
//! no out-of-memory, no hang). Three NPY ones declared a header of up to 4 GiB in a file of a
//! few bytes; `npy-nested-brackets-timeout.npy` nests 140 brackets in its header, which made
//! the header parser backtrack for minutes.

use drbokeh::color::Transfer;
use drbokeh::io::{ReadLimits, read_depth, read_layer, read_matte, read_photo};

#[test]
fn fuzzer_finds_are_refused() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fuzz");
    let limits = ReadLimits::default();
    let mut n = 0;
    let t = std::time::Instant::now();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        assert!(read_photo(&p, Transfer::Srgb, &limits).is_err(), "{}", p.display());
        assert!(read_depth(&p, &limits).is_err(), "{}", p.display());
        assert!(read_matte(&p, &limits).is_err(), "{}", p.display());
        let err = read_layer(&p, &limits).unwrap_err().to_string();
        assert!(err.contains(&*p.file_name().unwrap().to_string_lossy()), "{err}");
        n += 1;
    }
    assert!(n >= 4);
    assert!(t.elapsed().as_secs() < 5, "loaders took {:?}", t.elapsed());
}
