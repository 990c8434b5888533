//! The JSON the program writes keeps its shape when Rust types change: enums serialize to the
//! same strings and numbers the earlier strings and integers did (issue 15).

use drbokeh::config::Config;
use drbokeh::io::{BitDepth, OutputFormat};
use drbokeh::pipeline::{StageReport, StageStatus};
use serde_json::json;

#[test]
fn stage_reports_keep_their_json_shape() {
    let ran = serde_json::to_value(StageReport::ran("render", 12.5, Some(json!({"lens": 7})))).unwrap();
    assert_eq!(ran, json!({"name": "render", "status": "ran", "ms": 12.5, "detail": {"lens": 7}}));
    let skipped = serde_json::to_value(StageReport::skipped("inpaint", "layers were given")).unwrap();
    assert_eq!(skipped, json!({"name": "inpaint", "status": "skipped", "reason": "layers were given", "ms": 0.0}));
    assert_eq!(serde_json::to_value(StageStatus::Ran).unwrap(), json!("ran"));
    assert_eq!(serde_json::to_value(StageStatus::Skipped).unwrap(), json!("skipped"));
}

#[test]
fn config_output_format_and_bit_depth_keep_their_json_and_toml_shape() {
    // The config's JSON is hashed into batch fingerprints: it must not change.
    let v = serde_json::to_value(Config::default()).unwrap();
    assert_eq!(v["batch"]["output_format"], json!("png"));
    assert_eq!(v["output"]["bit_depth"], json!(8));
    for (name, format) in [("png", OutputFormat::Png), ("exr", OutputFormat::Exr), ("npy", OutputFormat::Npy)] {
        assert_eq!(serde_json::to_value(format).unwrap(), json!(name));
        assert_eq!(format.extension(), name);
        let cfg = Config::parse(&format!("[batch]\noutput_format = \"{name}\"\n")).unwrap();
        assert_eq!(cfg.batch.output_format, format);
    }
    for (bits, depth) in [(8u8, BitDepth::Eight), (16, BitDepth::Sixteen)] {
        assert_eq!(serde_json::to_value(depth).unwrap(), json!(bits));
        assert_eq!(depth.bits(), bits);
        assert_eq!(Config::parse(&format!("[output]\nbit_depth = {bits}\n")).unwrap().output.bit_depth, depth);
    }
    // Other values are refused when the file is parsed, naming the key or the valid values.
    let e = Config::parse("[output]\nbit_depth = 12\n").unwrap_err();
    assert!(e.contains("output.bit_depth") && e.contains("12"), "{e}");
    let e = Config::parse("[batch]\noutput_format = \"bmp\"\n").unwrap_err();
    assert!(e.contains("bmp") && e.contains("png") && e.contains("exr") && e.contains("npy"), "{e}");
}
