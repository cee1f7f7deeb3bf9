//! The seed corpus: small real files of every kind, made by the project's own code (its GLB
//! builder and exporter, the tracker's document, the CSV and mapping writers, the session
//! writer, the `image` crate's encoders) and, for the video reader, by FFmpeg's own tools
//! when they are installed. `examples/make_corpus.rs` writes them to `fuzz/corpus/`.

use std::path::Path;

use face::names::{ARKIT_NAMES, NUM_ARKIT};
use retarget::glb::{ARRAY_BUFFER, GlbBuilder};
use serde_json::{Value, json};

use crate::Target;
use crate::mutate::join_safetensors;

/// The seeds of `target`: (file name, bytes).
pub fn generate(target: Target) -> Vec<(String, Vec<u8>)> {
    let named = |list: Vec<(&str, Vec<u8>)>| {
        list.into_iter()
            .map(|(n, b)| (n.to_owned(), b))
            .collect::<Vec<_>>()
    };
    match target {
        Target::Puppet => named(puppets()),
        Target::TracksJson => named(tracks_json()),
        Target::LiveLinkCsv => named(live_link_csv()),
        Target::Mapping => named(mappings()),
        Target::Session => named(sessions()),
        Target::Image => named(images()),
        Target::Video => named(video()),
    }
}

/// A puppet's mesh: positions of a quad (two triangles) and per-target vertex offsets.
struct MeshSpec<'a> {
    names: &'a [&'a str],
    names_on_accessors: bool,
    u16_indices: bool,
    texcoords: bool,
    skinned: bool,
}

fn quad_positions() -> [f32; 12] {
    [-0.1, 0.0, 0.0, 0.1, 0.0, 0.0, 0.1, 0.2, 0.0, -0.1, 0.2, 0.0]
}

/// A small GLB puppet: Root > Neck > Head (holding the mesh), as the project's GLB builder
/// writes it.
fn puppet_doc(spec: &MeshSpec, extensions: Option<Value>) -> GlbBuilder {
    let mut doc = GlbBuilder::new(
        json!({"asset": {"version": "2.0", "generator": "likeness-fuzzing seeds"}}),
        Vec::new(),
    );
    let positions = quad_positions();
    let position = doc.float_accessor(&positions, "VEC3", Some(ARRAY_BUFFER), true);
    let normals: Vec<f32> = (0..4).flat_map(|_| [0.0, 0.0, 1.0]).collect();
    let normal = doc.float_accessor(&normals, "VEC3", Some(ARRAY_BUFFER), false);
    let indices = [0u32, 1, 2, 0, 2, 3];
    let index = if spec.u16_indices {
        let bytes: Vec<u8> = indices
            .iter()
            .flat_map(|&i| (i as u16).to_le_bytes())
            .collect();
        let view = doc.view(&bytes, Some(34963));
        doc.push(
            "accessors",
            json!({"bufferView": view, "componentType": 5123, "count": 6, "type": "SCALAR"}),
        )
    } else {
        doc.index_accessor(&indices)
    };
    let mut attributes = json!({"POSITION": position, "NORMAL": normal});
    if spec.texcoords {
        let uv = [0.0f32, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
        attributes["TEXCOORD_0"] =
            json!(doc.float_accessor(&uv, "VEC2", Some(ARRAY_BUFFER), false));
    }
    if spec.skinned {
        let joints: Vec<u8> = (0..4).flat_map(|_| [0u8, 1, 0, 0]).collect();
        let view = doc.view(&joints, Some(ARRAY_BUFFER));
        attributes["JOINTS_0"] = json!(doc.push(
            "accessors",
            json!({"bufferView": view, "componentType": 5121, "count": 4, "type": "VEC4"})
        ));
        let weights: Vec<f32> = (0..4).flat_map(|_| [0.5, 0.5, 0.0, 0.0]).collect();
        attributes["WEIGHTS_0"] =
            json!(doc.float_accessor(&weights, "VEC4", Some(ARRAY_BUFFER), false));
    }
    let mut targets = Vec::new();
    for (k, name) in spec.names.iter().enumerate() {
        let mut d = [0.0f32; 12];
        d[(k % 4) * 3 + 1] = 0.002 * (k as f32 + 1.0);
        let a = doc.float_accessor(&d, "VEC3", Some(ARRAY_BUFFER), true);
        if spec.names_on_accessors {
            doc.json["accessors"][a]["name"] = json!(name);
        }
        targets.push(json!({"POSITION": a}));
    }
    let mut primitive = json!({"attributes": attributes, "indices": index, "targets": targets});
    if spec.texcoords {
        let png = encode(&small_image(4, 4), image::ImageFormat::Png);
        let img = doc.image("skin", &png, "image/png");
        let sampler = doc.push("samplers", json!({"magFilter": 9729, "minFilter": 9987}));
        let texture = doc.push("textures", json!({"source": img, "sampler": sampler}));
        let material = doc.push(
            "materials",
            json!({"name": "skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": texture}, "baseColorFactor": [1.0, 0.8, 0.7, 1.0]}, "doubleSided": true}),
        );
        primitive["material"] = json!(material);
    }
    let mut mesh =
        json!({"name": "face", "primitives": [primitive], "weights": vec![0.0; spec.names.len()]});
    if !spec.names_on_accessors {
        mesh["extras"] = json!({"targetNames": spec.names});
    }
    let mesh = doc.push("meshes", mesh);
    let head = doc.push(
        "nodes",
        json!({"name": "Head", "mesh": mesh, "translation": [0.0, 0.1, 0.0]}),
    );
    let neck = doc.push(
        "nodes",
        json!({"name": "Neck", "children": [head], "rotation": [0.0, 0.0, 0.0, 1.0]}),
    );
    let root = doc.push(
        "nodes",
        json!({"name": "Root", "children": [neck], "scale": [1.0, 1.0, 1.0]}),
    );
    if spec.skinned {
        let ibm: Vec<f32> = (0..2)
            .flat_map(|_| glam::Mat4::IDENTITY.to_cols_array())
            .collect();
        let a = doc.float_accessor(&ibm, "MAT4", None, false);
        let skin = doc.push(
            "skins",
            json!({"joints": [neck, head], "inverseBindMatrices": a, "skeleton": root}),
        );
        doc.json["nodes"][head]["skin"] = json!(skin);
    }
    doc.json["scenes"] = json!([{"name": "scene", "nodes": [root]}]);
    doc.json["scene"] = json!(0);
    if let Some(ext) = extensions {
        let used: Vec<String> = ext
            .as_object()
            .map(|o| o.keys().cloned().collect())
            .unwrap_or_default();
        doc.json["extensions"] = ext;
        doc.json["extensionsUsed"] = json!(used);
    }
    doc
}

fn finish(doc: GlbBuilder) -> Vec<u8> {
    match doc.finish() {
        Ok(bytes) => bytes,
        Err(e) => panic!("a seed puppet does not build: {e}"),
    }
}

const VRM_TARGETS: [&str; 6] = [
    "jawOpen",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "mouthSmileLeft",
    "Fcl_MTH_A",
    "Fcl_ALL_Joy",
];

/// A VRM 1.0 puppet: ARKit-named morph targets plus preset and custom expressions with
/// overrides, the humanoid head bone (the mapping target's fixture too).
pub fn vrm1_puppet() -> Vec<u8> {
    let spec = MeshSpec {
        names: &VRM_TARGETS,
        names_on_accessors: false,
        u16_indices: false,
        texcoords: false,
        skinned: false,
    };
    let ext = json!({"VRMC_vrm": {
        "specVersion": "1.0",
        "humanoid": {"humanBones": {"head": {"node": 0}, "neck": {"node": 1}}},
        "expressions": {
            "preset": {
                "aa": {"morphTargetBinds": [{"node": 0, "index": 4, "weight": 1.0}]},
                "happy": {"morphTargetBinds": [{"node": 0, "index": 5, "weight": 0.8}], "overrideBlink": "blend", "overrideMouth": "block"},
                "blink": {"morphTargetBinds": [{"node": 0, "index": 1, "weight": 1.0}, {"node": 0, "index": 2, "weight": 1.0}], "isBinary": true},
                "lookUp": {"morphTargetBinds": []}
            },
            "custom": {
                "wink": {"morphTargetBinds": [{"node": 0, "index": 1, "weight": 0.5}], "overrideLookAt": "block"}
            }
        }
    }});
    finish(puppet_doc(&spec, Some(ext)))
}

/// A VRM 0.x puppet (blend shape groups, weights 0-100).
fn vrm0_puppet() -> Vec<u8> {
    let spec = MeshSpec {
        names: &VRM_TARGETS,
        names_on_accessors: true,
        u16_indices: false,
        texcoords: false,
        skinned: false,
    };
    let ext = json!({"VRM": {
        "exporterVersion": "likeness-fuzzing",
        "humanoid": {"humanBones": [{"bone": "head", "node": 0}, {"bone": "neck", "node": 1}]},
        "blendShapeMaster": {"blendShapeGroups": [
            {"name": "A", "presetName": "a", "binds": [{"mesh": 0, "index": 4, "weight": 100}]},
            {"name": "Joy", "presetName": "joy", "binds": [{"mesh": 0, "index": 5, "weight": 80}]},
            {"name": "Blink_L", "presetName": "blink_l", "binds": [{"mesh": 0, "index": 1, "weight": 100}], "isBinary": true},
            {"name": "Custom", "presetName": "unknown", "binds": [{"mesh": 0, "index": 3, "weight": 50}]}
        ]}
    }});
    finish(puppet_doc(&spec, Some(ext)))
}

fn base64(data: &[u8]) -> String {
    const ALPHABET: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[(n >> (18 - 6 * k)) as usize & 63] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

fn puppets() -> Vec<(&'static str, Vec<u8>)> {
    let arkit = MeshSpec {
        names: &["jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft"],
        names_on_accessors: false,
        u16_indices: false,
        texcoords: false,
        skinned: false,
    };
    let tiny = finish(puppet_doc(&arkit, None));
    let conventions = MeshSpec {
        names: &[
            "blendShape1.JawOpen",
            "Face:EyeBlink_L",
            "eyeBlink.R",
            "browInnerUp_L",
            "cheekPuff_R",
            "unrelated",
        ],
        names_on_accessors: true,
        u16_indices: true,
        texcoords: false,
        skinned: false,
    };
    let textured = MeshSpec {
        names: &["jawOpen", "tongueOut"],
        names_on_accessors: false,
        u16_indices: false,
        texcoords: true,
        skinned: true,
    };
    // The same tiny puppet as a .gltf with its buffer and an image as data URIs.
    let Some((json, bin)) = crate::mutate::split_glb(&tiny) else {
        panic!("the seed GLB does not split");
    };
    let bin = bin.unwrap_or_default();
    let mut embedded = serde_json::from_slice::<Value>(&json).unwrap_or(Value::Null);
    embedded["buffers"] = json!([{"uri": format!("data:application/octet-stream;base64,{}", base64(&bin)), "byteLength": bin.len()}]);
    let png = encode(&small_image(2, 2), image::ImageFormat::Png);
    embedded["images"] = json!([{"uri": format!("data:image/png;base64,{}", base64(&png))}]);
    embedded["textures"] = json!([{"source": 0}]);
    embedded["materials"] = json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
    embedded["meshes"][0]["primitives"][0]["material"] = json!(0);
    let gltf_text = serde_json::to_vec_pretty(&embedded).unwrap_or_default();
    vec![
        ("animation-export.glb", animation_export(&tiny)),
        ("conventions.glb", finish(puppet_doc(&conventions, None))),
        ("data-uri.gltf", gltf_text),
        ("textured-skinned.glb", finish(puppet_doc(&textured, None))),
        ("tiny.glb", tiny),
        ("vrm0.vrm", vrm0_puppet()),
        ("vrm1.vrm", vrm1_puppet()),
    ]
}

/// What `likeness retarget --out anim.glb` writes for `puppet` and a short clip.
fn animation_export(puppet: &[u8]) -> Vec<u8> {
    let path = Path::new("tiny.glb");
    let loaded = match retarget::Puppet::from_slice(puppet, path, None) {
        Ok(p) => p,
        Err(e) => panic!("the seed puppet does not load: {e}"),
    };
    let r = retarget::Retargeter::new(&loaded, &retarget::MappingData::default());
    let tracks = match retarget::Tracks::parse(&String::from_utf8_lossy(&track_document())) {
        Ok(t) => t,
        Err(e) => panic!("the seed tracking does not parse: {e}"),
    };
    let clip = retarget::export::retarget_clip(&r, &tracks);
    match retarget::export::animation_glb_bytes(
        puppet,
        None,
        &loaded,
        &r,
        &clip,
        Path::new("anim.glb"),
    ) {
        Ok(b) => b,
        Err(e) => panic!("the seed animation does not export: {e}"),
    }
}

/// The document `likeness track --out tracks.json` writes, for four frames (three with a
/// face, one without).
fn track_document() -> Vec<u8> {
    use tracking::record::{CameraRecord, FrameRecord, TracksDocument};
    let mut doc = TracksDocument::new("clip.mp4".into(), 30.0);
    doc.camera = Some(CameraRecord {
        width: 640,
        height: 480,
        focal_px: 600.0,
        cx: 320.0,
        cy: 240.0,
    });
    doc.settings =
        json!({"backend": "tract", "locator": "openseeface", "refine": true, "smoothing": 0.5});
    for k in 0..4 {
        let time_s = k as f64 / 30.0;
        if k == 2 {
            doc.frames.push(FrameRecord::no_face(
                k,
                time_s,
                Some("no face found".into()),
            ));
            continue;
        }
        let mut params = tracking::FaceParams::default();
        for (i, w) in params.weights.iter_mut().enumerate() {
            *w = ((i + k) % 7) as f32 / 7.0;
        }
        params.pose.euler_rad = glam::Vec3::new(0.1 * k as f32, -0.05, 0.02);
        let landmarks: [glam::Vec2; face::NUM_LANDMARKS] = std::array::from_fn(|i| {
            glam::Vec2::new(
                250.0 + (i % 17) as f32 * 8.0,
                200.0 + (i / 17) as f32 * 20.0,
            )
        });
        doc.frames
            .push(FrameRecord::with_face(k, time_s, &params, &landmarks, 0.93));
    }
    doc.to_json().into_bytes()
}

fn tracks_json() -> Vec<(&'static str, Vec<u8>)> {
    let third_party = json!({
        "arkit_names": ["JawOpen", "EyeBlink_L", "eyeBlink.R", "mouthSmileLeft", "notAChannel"],
        "frames": [
            {"time_s": 0.0, "arkit_weights": [0.1, 0.0, 0.0, 0.2, 5.0], "rotation_deg": [1.0, -2.0, 0.5]},
            {"time_s": 0.04, "arkit_weights": [0.6, 1.0, 0.9, 0.4, 5.0], "rotation_deg": [3.0, -1.0, 0.0], "translation": [0.0, 1.0, -60.0]},
            {"time_s": 0.08, "face": false},
            {"time_s": 0.12, "arkit_weights": [1.02, -0.01, 0.5, 0.0, 5.0]}
        ]
    });
    let by_index = json!({
        "arkit_names": ARKIT_NAMES.to_vec(),
        "frames": (0..3).map(|k| json!({"index": k, "arkit_weights": vec![k as f64 * 0.25; NUM_ARKIT]})).collect::<Vec<_>>()
    });
    vec![
        ("likeness-track.json", track_document()),
        (
            "third-party.json",
            serde_json::to_vec_pretty(&third_party).unwrap_or_default(),
        ),
        (
            "by-index.json",
            serde_json::to_vec(&by_index).unwrap_or_default(),
        ),
    ]
}

fn live_link_csv() -> Vec<(&'static str, Vec<u8>)> {
    let tracks = match retarget::Tracks::parse(&String::from_utf8_lossy(&track_document())) {
        Ok(t) => t,
        Err(e) => panic!("the seed tracking does not parse: {e}"),
    };
    // `likeness track --csv`: the tracked weights as they are.
    let raw = retarget::export::live_link_csv_raw(&tracks);
    // `likeness retarget --out anim.csv`: after a mapping's neutral calibration.
    let puppet = match retarget::Puppet::from_slice(&vrm1_puppet(), Path::new("p.vrm"), None) {
        Ok(p) => p,
        Err(e) => panic!("the seed puppet does not load: {e}"),
    };
    let mut mapping = retarget::MappingData::default();
    mapping.calibrate_neutral(&[0.1; NUM_ARKIT]);
    let r = retarget::Retargeter::new(&puppet, &mapping);
    let calibrated = retarget::export::live_link_csv(&r, &tracks);
    vec![
        ("track.csv", raw.into_bytes()),
        ("retarget.csv", calibrated.into_bytes()),
    ]
}

fn mappings() -> Vec<(&'static str, Vec<u8>)> {
    use retarget::mapping::{ChannelMapping, HeadMapping, MappingData};
    let save = |m: &MappingData| serde_json::to_vec_pretty(m).unwrap_or_default();
    let mut edited = MappingData::default();
    edited.channels.push(ChannelMapping {
        targets: vec!["jawOpen".into(), "Fcl_MTH_A".into()],
        gain: 1.2,
        offset: -0.05,
        clamp: [0.0, 0.9],
        curve: vec![[0.0, 0.0], [0.3, 0.1], [1.0, 1.0]],
        ..ChannelMapping::identity("JawOpen")
    });
    edited.channels.push(ChannelMapping {
        invert: true,
        ..ChannelMapping::identity("eyeBlink_L")
    });
    edited.calibrate_neutral(&std::array::from_fn(|a| (a % 5) as f32 * 0.05));
    edited.head = HeadMapping {
        enabled: true,
        node: Some("Neck".into()),
        gain: 0.5,
        mirror: true,
    };
    let mut vrm = MappingData::default();
    vrm.channels.push(ChannelMapping {
        targets: vec!["vrm:happy".into(), "wink".into()],
        ..ChannelMapping::identity("happy")
    });
    vrm.channels.push(ChannelMapping {
        targets: vec!["vrm:blink".into()],
        gain: 2.0,
        ..ChannelMapping::identity("blink")
    });
    vrm.head.enabled = false;
    vec![
        ("default.mapping.json", save(&MappingData::default())),
        ("edited.mapping.json", save(&edited)),
        ("vrm.mapping.json", save(&vrm)),
    ]
}

/// A session as `likeness personalize` (version 1 content: no footage) or the studio
/// (footage and observations) writes it, without its 21 MB of correction tensors: every
/// check of the file's own data comes before them.
fn sessions() -> Vec<(&'static str, Vec<u8>)> {
    use tracking::session::{FrameObservations, Session, SessionInfo};
    let tracks = match tracking::record::TracksDocument::from_json(&String::from_utf8_lossy(
        &track_document(),
    )) {
        Ok(t) => t,
        Err(e) => panic!("the seed tracking does not read: {e}"),
    };
    let info = SessionInfo {
        created_by: "likeness 0.1.0".into(),
        source: "clip.mp4".into(),
        selected_frames: vec![0, 1, 3],
        backend: "tract".into(),
        networks: "seed".into(),
    };
    let mut small_tracks = tracks.clone();
    if let Some(camera) = &mut small_tracks.camera {
        (camera.width, camera.height) = (6, 4);
        (camera.cx, camera.cy, camera.focal_px) = (3.0, 2.0, 6.0);
    }
    let count = small_tracks.frames.len();
    let studio = Session {
        info: info.clone(),
        corrections: face::PersonalCorrections::zeros(),
        footage: Some((0..count).map(|k| small_rgb(6, 4, k as u8)).collect()),
        observations: (0..count)
            .map(|k| FrameObservations {
                detected: vec![[1.0, 1.5], [2.0 + k as f32, 2.5]],
                crop: (k != 2).then_some([0.5, 0.5, 5.0, 3.0]),
            })
            .collect(),
        tracks: small_tracks,
    };
    let personalize = Session {
        info,
        corrections: face::PersonalCorrections::zeros(),
        tracks,
        footage: None,
        observations: Vec::new(),
    };
    let stripped = |s: &Session| match s.to_bytes() {
        Ok(bytes) => without_corrections(&bytes),
        Err(e) => panic!("the seed session does not serialise: {e}"),
    };
    vec![
        ("personalize.likeness", stripped(&personalize)),
        ("studio.likeness", stripped(&studio)),
    ]
}

/// A session file with its correction tensors removed (metadata and footage kept).
pub fn without_corrections(bytes: &[u8]) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap_or([0; 8])) as usize;
    let mut header: Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap_or(Value::Null);
    let data = &bytes[8 + n..];
    let mut kept = Vec::new();
    if let Some(tensors) = header.as_object_mut() {
        tensors.retain(|name, _| !matches!(name.as_str(), "dS0" | "dS" | "dR0" | "dR"));
        for (name, t) in tensors.iter_mut() {
            if name == "__metadata__" {
                continue;
            }
            let offsets = t["data_offsets"].as_array().cloned().unwrap_or_default();
            let (start, end) = (
                offsets.first().and_then(Value::as_u64).unwrap_or(0) as usize,
                offsets.get(1).and_then(Value::as_u64).unwrap_or(0) as usize,
            );
            let at = kept.len();
            kept.extend_from_slice(&data[start..end]);
            t["data_offsets"] = json!([at, kept.len()]);
        }
    }
    join_safetensors(&header, &kept)
}

fn small_rgb(w: u32, h: u32, shift: u8) -> image::RgbImage {
    image::RgbImage::from_fn(w, h, |x, y| {
        image::Rgb([(x * 40) as u8 ^ shift, (y * 60) as u8, ((x + y) * 20) as u8])
    })
}

fn small_image(w: u32, h: u32) -> image::DynamicImage {
    image::DynamicImage::ImageRgb8(small_rgb(w, h, 0))
}

fn encode(img: &image::DynamicImage, format: image::ImageFormat) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    match img.write_to(&mut out, format) {
        Ok(()) => out.into_inner(),
        Err(e) => panic!("a seed image does not encode as {format:?}: {e}"),
    }
}

fn images() -> Vec<(&'static str, Vec<u8>)> {
    use image::{DynamicImage, ImageFormat};
    let rgb = small_image(7, 5);
    let rgba = DynamicImage::ImageRgba8(rgb.to_rgba8());
    let gray16 = DynamicImage::ImageLuma16(rgb.to_luma16());
    let gray = DynamicImage::ImageLuma8(rgb.to_luma8());
    vec![
        ("rgb.png", encode(&rgb, ImageFormat::Png)),
        ("rgba.png", encode(&rgba, ImageFormat::Png)),
        ("gray16.png", encode(&gray16, ImageFormat::Png)),
        ("rgb.jpg", encode(&rgb, ImageFormat::Jpeg)),
        ("gray.jpg", encode(&gray, ImageFormat::Jpeg)),
        ("rgb.bmp", encode(&rgb, ImageFormat::Bmp)),
        ("rgba.tiff", encode(&rgba, ImageFormat::Tiff)),
        ("rgba.webp", encode(&rgba, ImageFormat::WebP)),
    ]
}

fn with_mode(mode: u8, rest: &[u8]) -> Vec<u8> {
    let mut out = vec![mode];
    out.extend_from_slice(rest);
    out
}

/// Runs an FFmpeg tool, its standard output if it succeeded.
fn ffmpeg_tool(program: &str, args: &[&str]) -> Option<Vec<u8>> {
    let out = std::process::Command::new(program)
        .args(args)
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    out.status.success().then_some(out.stdout)
}

fn video() -> Vec<(&'static str, Vec<u8>)> {
    let mut seeds = vec![
        (
            "input-names.txt",
            with_mode(3, b"ffmpeg:lavfi:testsrc2=size=640x480:rate=30"),
        ),
        ("input-webcam.txt", with_mode(3, b"webcam:/dev/video1")),
        (
            "folder-order.txt",
            with_mode(
                4,
                b"frames/frame_10.png\nframes/frame_2.png\nframes/frame_002.png\nframes/Frame_1.jpg\nframes/frame_1b.png\nframes/a.png\n",
            ),
        ),
    ];
    // What ffprobe says about real encodings, and ffmpeg's raw frames.
    let dir = std::env::temp_dir().join(format!("likeness-fuzzing-seeds-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let probe_args = [
        "-v",
        "error",
        "-select_streams",
        "v:0",
        "-show_entries",
        "stream=width,height,avg_frame_rate,r_frame_rate,nb_frames",
        "-of",
        "json",
    ];
    for (name, codec, file) in [
        ("probe-mpeg4.json", "mpeg4", "clip.mp4"),
        ("probe-mjpeg.json", "mjpeg", "clip.avi"),
        ("probe-ffv1.json", "ffv1", "clip.mkv"),
    ] {
        let path = dir.join(file);
        let path_text = path.to_string_lossy().into_owned();
        let made = ffmpeg_tool(
            "ffmpeg",
            &[
                "-nostdin",
                "-y",
                "-v",
                "error",
                "-f",
                "lavfi",
                "-i",
                "testsrc2=size=64x48:rate=30000/1001",
                "-frames:v",
                "3",
                "-c:v",
                codec,
                &path_text,
            ],
        );
        let mut args: Vec<&str> = probe_args.to_vec();
        args.push(&path_text);
        if let Some(json) = made.and_then(|_| ffmpeg_tool("ffprobe", &args)) {
            seeds.push((name, with_mode(0, &json)));
        }
    }
    if let Some(size) = ffmpeg_tool(
        "ffprobe",
        &[
            "-v",
            "error",
            "-f",
            "lavfi",
            "-i",
            "testsrc2=size=64x48",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height",
            "-of",
            "csv=p=0",
        ],
    ) {
        seeds.push(("live-size.txt", with_mode(1, &size)));
    }
    if let Some(raw) = ffmpeg_tool(
        "ffmpeg",
        &[
            "-nostdin",
            "-v",
            "error",
            "-f",
            "lavfi",
            "-i",
            "testsrc2=size=5x3:rate=5",
            "-frames:v",
            "3",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
            "-",
        ],
    ) {
        // Width 5, height 3, three read sizes, the sizes, the stream.
        let mut rest = vec![4, 2, 3, 7, 0, 200];
        rest.extend_from_slice(&raw);
        seeds.push(("raw-frames.bin", with_mode(2, &rest)));
    }
    let _ = std::fs::remove_dir_all(&dir);
    seeds
}

/// A face model on a four-vertex template (one quad in the face's UV tile), for the
/// studio's session reader: it needs a model, not the ICT FaceKit's 26k vertices.
#[cfg(feature = "studio")]
pub fn tiny_face_model() -> &'static face::FaceModel {
    static MODEL: std::sync::OnceLock<face::FaceModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| {
        face::FaceModel::new(face::Template::one_quad("likeness-fuzzing tiny template"))
    })
}
