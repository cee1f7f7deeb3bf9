//! Small puppets built in the tests, so every convention and every breakage is covered
//! without shipping third-party files.

#![allow(dead_code)]

use retarget::glb::{ARRAY_BUFFER, GlbBuilder};
use serde_json::{Value, json};
use std::cell::Cell;

use retarget::Puppet;

pub enum Naming {
    Extras,
    Accessors,
}

/// One triangle whose morph target k moves vertex 0 up by (k + 1) mm; names as given.
pub fn tiny_puppet(names: &[String], naming: Naming, extensions: Option<Value>) -> Vec<u8> {
    let mut doc = GlbBuilder::new(json!({"asset": {"version": "2.0"}}), Vec::new());
    let positions = [0.0f32, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1, 0.0];
    let position = doc.float_accessor(&positions, "VEC3", Some(ARRAY_BUFFER), true);
    let mut targets = Vec::new();
    for (k, name) in names.iter().enumerate() {
        let d = [
            0.0f32,
            0.001 * (k as f32 + 1.0),
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ];
        let a = doc.float_accessor(&d, "VEC3", Some(ARRAY_BUFFER), true);
        if let Naming::Accessors = naming {
            doc.json["accessors"][a]["name"] = json!(name);
        }
        targets.push(json!({"POSITION": a}));
    }
    let mut mesh = json!({"name": "face", "primitives": [{"attributes": {"POSITION": position}, "targets": targets}]});
    if let Naming::Extras = naming {
        mesh["extras"] = json!({"targetNames": names});
    }
    let mesh = doc.push("meshes", mesh);
    let head = doc.push("nodes", json!({"name": "Head", "mesh": mesh}));
    let root = doc.push("nodes", json!({"name": "Root", "children": [head]}));
    doc.json["scenes"] = json!([{"nodes": [root]}]);
    doc.json["scene"] = json!(0);
    if let Some(ext) = extensions {
        doc.json["extensions"] = ext;
        doc.json["extensionsUsed"] = json!(["VRMC_vrm"]);
    }
    doc.finish().expect("tiny puppet")
}

/// Splits a GLB into its JSON and binary chunk (for corrupting tests).
pub fn glb_parts(bytes: &[u8]) -> (Value, Vec<u8>) {
    let glb = gltf::Glb::from_slice(bytes).expect("GLB");
    (
        serde_json::from_slice(&glb.json).expect("JSON"),
        glb.bin.map(|b| b.into_owned()).unwrap_or_default(),
    )
}

/// Reassembles a GLB from (possibly edited) JSON and binary chunk.
pub fn glb_from(json: &Value, bin: Vec<u8>) -> Vec<u8> {
    let glb = gltf::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: serde_json::to_vec(json).unwrap().into(),
        bin: Some(bin.into()),
    };
    glb.to_vec().unwrap()
}

pub fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("likeness-retarget-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

thread_local! {
    static PANICKED: Cell<bool> = const { Cell::new(false) };
}

/// Loads `bytes`, failing the test if anything panicked on the way, even a panic the loader
/// caught itself (its last-resort guard must never be what saves a known file).
pub fn load_detecting_panics(
    bytes: &[u8],
    base: Option<&std::path::Path>,
) -> Result<Puppet, String> {
    static HOOK: std::sync::Once = std::sync::Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            PANICKED.with(|p| p.set(true));
            previous(info);
        }));
    });
    PANICKED.with(|p| p.set(false));
    let result = Puppet::from_slice(bytes, std::path::Path::new("hostile.gltf"), base);
    assert!(
        !PANICKED.with(Cell::get),
        "the loader panicked (and caught it) on this file"
    );
    result.map_err(|e| e.to_string())
}

/// Runs the Khronos glTF validator (npm `gltf-validator`, installed into
/// tools/gltf-validator by scripts/setup.sh) on `file`: errors fail the test; warnings and
/// infos are printed.
pub fn validate(file: &std::path::Path) {
    let script = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tools/gltf-validator/validate.mjs");
    let modules = script.with_file_name("node_modules").join("gltf-validator");
    assert!(
        modules.is_dir(),
        "the Khronos validator is not installed: run scripts/setup.sh (npm install in tools/gltf-validator)"
    );
    let out = std::process::Command::new("node")
        .arg(&script)
        .arg(file)
        .output()
        .unwrap_or_else(|e| panic!("cannot run node ({e}): run scripts/setup.sh"));
    let report = String::from_utf8_lossy(&out.stdout);
    let issues: serde_json::Value = serde_json::from_str(report.trim()).unwrap_or_else(|e| {
        panic!(
            "validator output is not JSON ({e}): {report} {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let errors = issues["numErrors"].as_u64().unwrap_or(u64::MAX);
    let messages: Vec<String> = issues["messages"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|m| {
            format!(
                "[{}] {} {} {}",
                m["severity"], m["code"], m["pointer"], m["message"]
            )
        })
        .collect();
    println!(
        "{}: {errors} errors, {} warnings\n{}",
        file.display(),
        issues["numWarnings"],
        messages.join("\n")
    );
    assert_eq!(errors, 0, "{}:\n{}", file.display(), messages.join("\n"));
}
