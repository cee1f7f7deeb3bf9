//! Where puppet data comes from: external and data-URI buffers, external images (embedded by
//! the GLB export), and skins (read, and not broken by).

mod common;

use common::{Naming, glb_parts, temp_dir, tiny_puppet};
use retarget::export::{retarget_clip, write_animation_glb};
use retarget::{MappingData, Puppet, Retargeter, Tracks};
use serde_json::json;

const PNG_2X2: &[u8] = &[
    0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a, 0x00, 0x00, 0x00, 0x0d, 0x49, 0x48, 0x44, 0x52,
    0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01, 0x08, 0x02, 0x00, 0x00, 0x00, 0x90, 0x77, 0x53,
    0xde, 0x00, 0x00, 0x00, 0x0c, 0x49, 0x44, 0x41, 0x54, 0x08, 0xd7, 0x63, 0xf8, 0xcf, 0xc0, 0x00,
    0x00, 0x03, 0x01, 0x01, 0x00, 0x18, 0xdd, 0x8d, 0xb0, 0x00, 0x00, 0x00, 0x00, 0x49, 0x45, 0x4e,
    0x44, 0xae, 0x42, 0x60, 0x82,
];

fn names() -> Vec<String> {
    vec!["jawOpen".into(), "eyeBlinkLeft".into()]
}

#[test]
fn external_and_data_uri_buffers_load_like_the_glb() {
    let dir = temp_dir("sources");
    let glb = tiny_puppet(&names(), Naming::Extras, None);
    let reference = Puppet::from_slice(&glb, std::path::Path::new("ref.glb"), None).unwrap();
    let (json, bin) = glb_parts(&glb);

    // .gltf + external .bin (with a space in its name) + an external texture.
    let mut external = json.clone();
    external["buffers"] = json!([{"uri": "tiny%20data.bin", "byteLength": bin.len()}]);
    external["images"] = json!([{"uri": "skin.png"}]);
    external["textures"] = json!([{"source": 0}]);
    external["materials"] = json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "baseColorFactor": [1.0, 0.5, 0.5, 1.0]}}]);
    external["meshes"][0]["primitives"][0]["material"] = json!(0);
    std::fs::write(dir.join("tiny data.bin"), &bin).unwrap();
    std::fs::write(dir.join("skin.png"), PNG_2X2).unwrap();
    let path = dir.join("external.gltf");
    std::fs::write(&path, serde_json::to_vec(&external).unwrap()).unwrap();
    let loaded = Puppet::load(&path).unwrap();
    let mut without_material = loaded.meshes.clone();
    without_material[0].primitives[0].material = None;
    assert_eq!(without_material, reference.meshes);
    assert_eq!(loaded.images.len(), 1);
    assert_eq!((loaded.images[0].width, loaded.images[0].height), (1, 1));
    assert_eq!(loaded.materials[0].base_color_image, Some(0));

    // .gltf with the buffer as a data URI.
    let mut inline = json.clone();
    inline["buffers"] = json!([{"uri": format!("data:application/octet-stream;base64,{}", base64_encode(&bin)), "byteLength": bin.len()}]);
    let path_inline = dir.join("inline.gltf");
    std::fs::write(&path_inline, serde_json::to_vec(&inline).unwrap()).unwrap();
    assert_eq!(Puppet::load(&path_inline).unwrap().meshes, reference.meshes);

    // The animation export of the .gltf is one self-contained GLB: buffer and image inside.
    let r = Retargeter::new(&loaded, &MappingData::default());
    let tracks = Tracks::parse(r#"{"arkit_names": ["jawOpen"], "frames": [{"arkit_weights": [0.2]}, {"arkit_weights": [0.9]}]}"#).unwrap();
    let out = dir.join("moved").join("anim.glb");
    std::fs::create_dir_all(out.parent().unwrap()).unwrap();
    write_animation_glb(&loaded, &r, &retarget_clip(&r, &tracks), &out).unwrap();
    let (exported, _) = glb_parts(&std::fs::read(&out).unwrap());
    assert!(
        exported["images"][0].get("uri").is_none()
            && exported["images"][0]["mimeType"] == "image/png"
    );
    assert_eq!(exported["buffers"].as_array().unwrap().len(), 1);
    let again = Puppet::load(&out).unwrap();
    assert_eq!(again.meshes, loaded.meshes);
    assert_eq!(again.images, loaded.images);
}

#[test]
fn skinned_puppets_load_and_retarget() {
    let glb = tiny_puppet(&names(), Naming::Extras, None);
    let (mut json, mut bin) = glb_parts(&glb);
    // JOINTS_0 (unsigned short) and WEIGHTS_0 for the 3 vertices, a skin of two joints.
    let joints: Vec<u8> = [0u16, 1, 0, 0]
        .repeat(3)
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let weights: Vec<u8> = [0.5f32, 0.5, 0.0, 0.0]
        .repeat(3)
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let ibm: Vec<u8> = [
        1.0f32, 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.,
    ]
    .repeat(2)
    .iter()
    .flat_map(|v| v.to_le_bytes())
    .collect();
    let mut add = |data: &[u8], component: u32, kind: &str, count: usize| {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let views = json["bufferViews"].as_array_mut().unwrap();
        views.push(json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": data.len()}));
        let view = views.len() - 1;
        bin.extend_from_slice(data);
        let accessors = json["accessors"].as_array_mut().unwrap();
        accessors.push(
            json!({"bufferView": view, "componentType": component, "count": count, "type": kind}),
        );
        accessors.len() - 1
    };
    let j = add(&joints, 5123, "VEC4", 3);
    let w = add(&weights, 5126, "VEC4", 3);
    let m = add(&ibm, 5126, "MAT4", 2);
    json["buffers"][0]["byteLength"] = json!(bin.len());
    json["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"] = json!(j);
    json["meshes"][0]["primitives"][0]["attributes"]["WEIGHTS_0"] = json!(w);
    json["skins"] = json!([{"joints": [0, 1], "inverseBindMatrices": m}]);
    json["nodes"][0]["skin"] = json!(0);
    let puppet = Puppet::from_slice(
        &common::glb_from(&json, bin),
        std::path::Path::new("skinned.glb"),
        None,
    )
    .unwrap();
    assert_eq!(puppet.skins.len(), 1);
    assert_eq!(puppet.skins[0].joints, vec![0, 1]);
    assert_eq!(puppet.meshes[0].primitives[0].joints[1], [0, 1, 0, 0]);
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert_eq!(r.report.mapped.len(), 2);
}

fn base64_encode(data: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(ALPHABET[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}
