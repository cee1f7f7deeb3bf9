//! Malformed puppets are clear errors naming the problem, never panics.

mod common;

use common::{Naming, glb_from, glb_parts, load_detecting_panics, temp_dir, tiny_puppet};
use retarget::Puppet;
use serde_json::json;
use std::path::Path;

fn names(n: usize) -> Vec<String> {
    (0..n).map(|k| format!("t{k}")).collect()
}

fn error_of(bytes: &[u8]) -> String {
    match Puppet::from_slice(bytes, Path::new("bad.glb"), None) {
        Ok(_) => panic!("a malformed puppet loaded"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn each_breakage_names_its_problem() {
    let good = tiny_puppet(&names(2), Naming::Extras, None);
    let (json, bin) = glb_parts(&good);

    let mut cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("0-byte file", Vec::new(), "empty"),
        (
            "wrong magic",
            b"PK\x03\x04 not a glb".to_vec(),
            "not a glTF file",
        ),
        ("truncated", good[..good.len() / 2].to_vec(), "GLB"),
        ("header only", good[..12].to_vec(), "GLB"),
    ];
    // A JSON chunk that is not JSON.
    let mut not_json = good.clone();
    not_json[20] = b'#';
    cases.push(("JSON chunk not JSON", not_json, "not JSON"));

    let mut j = json.clone();
    j["accessors"][0]["count"] = json!(1000);
    cases.push((
        "accessor past its buffer view",
        glb_from(&j, bin.clone()),
        "accessor 0",
    ));

    let mut j = json.clone();
    j["bufferViews"][0]["byteLength"] = json!(1 << 20);
    cases.push((
        "buffer view past its buffer",
        glb_from(&j, bin.clone()),
        "buffer",
    ));

    let mut nan_bin = bin.clone();
    nan_bin[0..4].copy_from_slice(&f32::NAN.to_le_bytes());
    cases.push(("NaN position", glb_from(&json, nan_bin), "not finite"));

    let mut j = json.clone();
    j["extensionsRequired"] = json!(["KHR_draco_mesh_compression", "EXT_meshopt_compression"]);
    j["extensionsUsed"] = json!(["KHR_draco_mesh_compression", "EXT_meshopt_compression"]);
    cases.push((
        "unsupported required extensions",
        glb_from(&j, bin.clone()),
        "KHR_draco_mesh_compression, EXT_meshopt_compression",
    ));

    let mut j = json.clone();
    j["nodes"][0]["children"] = json!([1]);
    cases.push(("node cycle", glb_from(&j, bin.clone()), "cycle"));

    cases.push((
        "thousands of morph targets",
        tiny_puppet(&names(3000), Naming::Extras, None),
        "3000 morph targets",
    ));

    for (what, bytes, expect) in cases {
        let err = error_of(&bytes);
        assert!(err.contains(expect), "{what}: {err}");
        assert!(
            err.contains("bad.glb"),
            "{what}: the error names the file: {err}"
        );
    }
}

#[test]
fn missing_and_unreadable_files_are_errors() {
    let dir = temp_dir("bad-files");
    let err = Puppet::load(&dir.join("nope.glb")).unwrap_err().to_string();
    assert!(err.contains("nope.glb"), "{err}");
    let empty = dir.join("empty.vrm");
    std::fs::write(&empty, b"").unwrap();
    assert!(
        Puppet::load(&empty)
            .unwrap_err()
            .to_string()
            .contains("empty")
    );
    // A .gltf whose external buffer is missing.
    let gltf = dir.join("external.gltf");
    std::fs::write(&gltf, serde_json::to_vec(&json!({"asset": {"version": "2.0"}, "buffers": [{"uri": "missing.bin", "byteLength": 36}]})).unwrap()).unwrap();
    let err = Puppet::load(&gltf).unwrap_err().to_string();
    assert!(
        err.contains("buffer 0") && err.contains("missing.bin"),
        "{err}"
    );
}

/// Deterministic corruption of a real puppet: truncations and byte flips everywhere. The
/// loader may refuse or accept each, but must never panic. (`fuzz/` runs the same target
/// under libFuzzer for longer.)
#[test]
fn corrupted_puppets_never_panic() {
    let style = &retarget::generator::styles()[0];
    let good = retarget::generator::glb_bytes(style).unwrap();
    let mut inputs: Vec<Vec<u8>> = Vec::new();
    for cut in (0..good.len()).step_by(good.len() / 97 + 1) {
        inputs.push(good[..cut].to_vec());
    }
    // Flip bytes in the header, the JSON chunk and the binary chunk.
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    for _ in 0..400 {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        let mut b = good.clone();
        let at = (x % b.len() as u64) as usize;
        b[at] ^= (x >> 32) as u8 | 1;
        inputs.push(b);
    }
    for bytes in &inputs {
        // Fails the test on any panic, even one the loader's last-resort guard caught.
        let _ = load_detecting_panics(bytes, None).map(|p| p.morph_target_count());
    }
}
