//! Files crafted to break the loader or to smuggle local files into exports: every one is a
//! clear error or loads safely, never a panic, and no byte of a file outside the puppet's
//! folder reaches an export. Each panic the `gltf` crate had on such files has a case here.

mod common;

use std::path::PathBuf;

use common::{Naming, glb_from, glb_parts, load_detecting_panics, temp_dir, tiny_puppet, validate};
use face::names::{NUM_ARKIT, arkit_index};
use retarget::export::{ANIMATION_NAME, retarget_clip, write_animation_glb};
use retarget::glb::GlbBuilder;
use retarget::tracks::TrackedFrame;
use retarget::{MappingData, Puppet, Retargeter, Tracks};
use serde_json::{Value, json};

fn names(n: usize) -> Vec<String> {
    (0..n).map(|k| format!("t{k}")).collect()
}

#[test]
fn the_crash_files_are_clear_errors() {
    // 1. The 160-byte file: a POSITION attribute and no `accessors` at all (the `gltf`
    //    crate's own validation indexed the missing array).
    let tiny = br#"{"asset":{"version":"2.0"},"meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],"nodes":[{"mesh":0}],"scenes":[{"nodes":[0]}]}"#;
    let err = load_detecting_panics(tiny, None).unwrap_err();
    assert!(
        err.contains("POSITION") && err.contains("accessor 0"),
        "{err}"
    );

    let good = tiny_puppet(&names(2), Naming::Extras, None);
    let (json, bin) = glb_parts(&good);
    // The accessor reads a fresh 256-byte view of zeros, so that only its type is wrong.
    let with_accessor = |attribute: &str, mut accessor: Value| {
        let mut doc = GlbBuilder::new(json.clone(), bin.clone());
        accessor["bufferView"] = json!(doc.view(&[0u8; 256], None));
        let k = doc.push("accessors", accessor);
        if attribute == "indices" {
            doc.json["meshes"][0]["primitives"][0]["indices"] = json!(k);
        } else {
            doc.json["meshes"][0]["primitives"][0]["attributes"][attribute] = json!(k);
        }
        doc.finish().unwrap()
    };
    // 2. Index and attribute accessors of component types the crate's reader did not
    //    expect (`unreachable!()` there).
    for (attribute, accessor, expect) in [
        (
            "indices",
            json!({"bufferView": 0, "componentType": 5126, "count": 3, "type": "SCALAR"}),
            "indices",
        ),
        (
            "indices",
            json!({"bufferView": 0, "componentType": 5123, "count": 3, "type": "VEC3"}),
            "indices",
        ),
        (
            "TEXCOORD_0",
            json!({"bufferView": 0, "componentType": 5125, "count": 3, "type": "VEC2"}),
            "TEXCOORD_0",
        ),
        (
            "JOINTS_0",
            json!({"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC4"}),
            "JOINTS_0",
        ),
        (
            "WEIGHTS_0",
            json!({"bufferView": 0, "componentType": 5125, "count": 3, "type": "VEC4"}),
            "WEIGHTS_0",
        ),
        (
            "NORMAL",
            json!({"bufferView": 0, "componentType": 5126, "count": 0, "type": "VEC3"}),
            "NORMAL",
        ),
    ] {
        let err =
            load_detecting_panics(&with_accessor(attribute, accessor.clone()), None).unwrap_err();
        assert!(err.contains(expect), "{accessor}: {err}");
    }
    // 16-bit indices done right load, with their values.
    let mut doc = GlbBuilder::new(json.clone(), bin.clone());
    let view = doc.view(&[2u16, 1, 0, 0].map(u16::to_le_bytes).concat(), None);
    let k = doc.push(
        "accessors",
        json!({"bufferView": view, "componentType": 5123, "count": 3, "type": "SCALAR"}),
    );
    doc.json["meshes"][0]["primitives"][0]["indices"] = json!(k);
    let puppet = load_detecting_panics(&doc.finish().unwrap(), None).unwrap();
    assert_eq!(puppet.meshes[0].primitives[0].indices, vec![2, 1, 0]);

    // 3. An image in a buffer view without a MIME type (the crate unwrapped it): the
    //    puppet loads, the image is drawn white.
    let mut doc = GlbBuilder::new(json.clone(), bin.clone());
    let view = doc.view(b"not really a png", None);
    doc.push("images", json!({"bufferView": view}));
    let puppet = load_detecting_panics(&doc.finish().unwrap(), None).unwrap();
    assert_eq!(puppet.images.len(), 1);
    assert_eq!((puppet.images[0].width, puppet.images[0].height), (1, 1));

    // 4. A sparse accessor with no buffer view claiming two billion elements.
    let mut doc = GlbBuilder::new(json.clone(), bin.clone());
    let indices = doc.view(&0u32.to_le_bytes(), None);
    let values = doc.view(&[0u8; 12], None);
    let k = doc.push(
        "accessors",
        json!({"componentType": 5126, "count": 2_000_000_000u64, "type": "VEC3",
               "sparse": {"count": 1, "indices": {"bufferView": indices, "componentType": 5125},
                          "values": {"bufferView": values}}}),
    );
    doc.json["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = json!(k);
    let err = load_detecting_panics(&doc.finish().unwrap(), None).unwrap_err();
    assert!(err.contains("NORMAL"), "{err}");

    // 5. A transform with no rotation to decompose (all zeros: its rotation is NaN).
    let mut j = json.clone();
    j["nodes"][0]["matrix"] = json!(vec![0.0; 16]);
    let err = load_detecting_panics(&glb_from(&j, bin.clone()), None).unwrap_err();
    assert!(err.contains("node 0") && err.contains("finite"), "{err}");
}

#[test]
fn a_node_tree_that_is_not_a_tree_is_refused() {
    let good = tiny_puppet(&names(1), Naming::Extras, None);
    let (json, bin) = glb_parts(&good);
    // Nodes: 0 Head, 1 Root -> [0]. Add 2 and 3 forming a cycle behind node 0's second
    // parent: 1 -> 0, 2 -> 0 (two parents), 2 <-> 3.
    let mut j = json.clone();
    j["nodes"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "a", "children": [0, 3]}));
    j["nodes"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "b", "children": [2]}));
    let err = load_detecting_panics(&glb_from(&j, bin.clone()), None).unwrap_err();
    assert!(err.contains("child of both"), "{err}");
    // Only the cycle (no node with two parents).
    let mut j = json.clone();
    j["nodes"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "a", "children": [3]}));
    j["nodes"]
        .as_array_mut()
        .unwrap()
        .push(json!({"name": "b", "children": [2]}));
    let err = load_detecting_panics(&glb_from(&j, bin.clone()), None).unwrap_err();
    assert!(err.contains("cycle"), "{err}");
    let mut j = json;
    j["nodes"][0]["children"] = json!([0]);
    let err = load_detecting_panics(&glb_from(&j, bin), None).unwrap_err();
    assert!(err.contains("cycle"), "{err}");
}

#[test]
fn draco_is_named_when_it_is_the_reason() {
    // A valid Draco file that does not require the extension: its accessors have no
    // buffer view (the data is in the Draco stream).
    let good = tiny_puppet(&names(1), Naming::Extras, None);
    let (mut j, bin) = glb_parts(&good);
    j["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
    j["accessors"][0]
        .as_object_mut()
        .unwrap()
        .remove("bufferView");
    j["meshes"][0]["primitives"][0]["extensions"] =
        json!({"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {"POSITION": 0}}});
    let err = load_detecting_panics(&glb_from(&j, bin), None).unwrap_err();
    assert!(err.contains("KHR_draco_mesh_compression"), "{err}");
}

/// A folder with a `.gltf` puppet whose buffer is an external file, and beside the folder a
/// secret the puppet must never reach.
struct Scene {
    dir: PathBuf,
    puppet_dir: PathBuf,
    json: Value,
}

const SECRET: &[u8] = b"LIKENESS-SECRET-7c1f0e-do-not-export";

impl Scene {
    fn new(name: &str) -> Self {
        let dir = temp_dir(&format!("hostile-{name}"));
        let puppet_dir = dir.join("puppet");
        std::fs::create_dir_all(&puppet_dir).unwrap();
        std::fs::write(dir.join("secret.txt"), SECRET).unwrap();
        let (mut json, bin) = glb_parts(&tiny_puppet(
            &["jawOpen".to_owned(), "eyeBlinkLeft".to_owned()],
            Naming::Extras,
            None,
        ));
        std::fs::write(puppet_dir.join("mesh.bin"), &bin).unwrap();
        json["buffers"] = json!([{"uri": "mesh.bin", "byteLength": bin.len()}]);
        Self {
            dir,
            puppet_dir,
            json,
        }
    }

    /// Adds a textured material on the mesh showing an image at `uri`.
    fn with_texture(mut self, uri: &str) -> Self {
        // A texture needs texture coordinates on the mesh.
        let bin_path = self.puppet_dir.join("mesh.bin");
        let mut bin = std::fs::read(&bin_path).unwrap();
        let offset = bin.len();
        for v in [0.0f32, 0.0, 1.0, 0.0, 0.0, 1.0] {
            bin.extend_from_slice(&v.to_le_bytes());
        }
        std::fs::write(&bin_path, &bin).unwrap();
        self.json["buffers"][0]["byteLength"] = json!(bin.len());
        let views = self.json["bufferViews"].as_array_mut().unwrap();
        views.push(json!({"buffer": 0, "byteOffset": offset, "byteLength": 24}));
        let view = views.len() - 1;
        let accessors = self.json["accessors"].as_array_mut().unwrap();
        accessors
            .push(json!({"bufferView": view, "componentType": 5126, "count": 3, "type": "VEC2"}));
        let uv = accessors.len() - 1;
        self.json["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"] = json!(uv);
        self.json["images"] = json!([{"uri": uri}]);
        self.json["textures"] = json!([{"source": 0}]);
        self.json["materials"] =
            json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
        self.json["meshes"][0]["primitives"][0]["material"] = json!(0);
        self
    }

    fn write(&self) -> PathBuf {
        let path = self.puppet_dir.join("hostile.gltf");
        std::fs::write(&path, serde_json::to_vec(&self.json).unwrap()).unwrap();
        path
    }

    /// Loads, exports the animation, and returns the export's bytes.
    fn export(&self) -> Result<Vec<u8>, String> {
        let path = self.write();
        let puppet = Puppet::load(&path).map_err(|e| e.to_string())?;
        let r = Retargeter::new(&puppet, &MappingData::default());
        let mut arkit = [0.0f32; NUM_ARKIT];
        arkit[arkit_index("jawOpen").unwrap()] = 1.0;
        let tracks = Tracks {
            frames: (0..3)
                .map(|k| TrackedFrame {
                    time_s: k as f32 / 30.0,
                    arkit,
                    rotation_deg: None,
                })
                .collect(),
            ..Tracks::default()
        };
        let out = self.dir.join("out.glb");
        write_animation_glb(&puppet, &r, &retarget_clip(&r, &tracks), &out)
            .map_err(|e| e.to_string())?;
        // Whatever was left out or replaced, the export is valid glTF.
        validate(&out);
        Ok(std::fs::read(out).unwrap())
    }
}

fn contains(haystack: &[u8], needle: &[u8]) -> bool {
    haystack.windows(needle.len()).any(|w| w == needle)
}

fn png_bytes(rgb: [u8; 3]) -> Vec<u8> {
    let mut bytes = Vec::new();
    image::RgbaImage::from_pixel(2, 2, image::Rgba([rgb[0], rgb[1], rgb[2], 255]))
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .unwrap();
    bytes
}

#[test]
fn images_outside_the_puppets_folder_never_reach_an_export() {
    let absolute_secret = Scene::new("abs").dir.join("secret.txt");
    let mut attacks = vec![
        "../secret.txt".to_owned(),
        "../../../../../../../../etc/passwd".to_owned(),
        "%2e%2e/secret.txt".to_owned(),
        "..%5Csecret.txt".to_owned(),
        "/etc/passwd".to_owned(),
        "/proc/self/environ".to_owned(),
        "file:///etc/passwd".to_owned(),
        absolute_secret.display().to_string(),
        format!("file://{}", absolute_secret.display()),
        "/dev/zero".to_owned(),
        "link-to-secret.txt".to_owned(),
        "link-to-dev-zero".to_owned(),
    ];
    attacks.push("link-to-parent/secret.txt".to_owned());
    for uri in attacks {
        let scene = Scene::new("image").with_texture(&uri);
        #[cfg(unix)]
        {
            let p = &scene.puppet_dir;
            std::os::unix::fs::symlink(scene.dir.join("secret.txt"), p.join("link-to-secret.txt"))
                .unwrap();
            std::os::unix::fs::symlink("/dev/zero", p.join("link-to-dev-zero")).unwrap();
            std::os::unix::fs::symlink(&scene.dir, p.join("link-to-parent")).unwrap();
        }
        let exported = scene.export().unwrap_or_else(|e| panic!("{uri}: {e}"));
        assert!(
            !contains(&exported, SECRET),
            "{uri}: the secret is in the export"
        );
        assert!(
            !contains(&exported, b"root:x:0:0"),
            "{uri}: /etc/passwd is in the export"
        );
        assert!(
            !contains(&exported, b"PATH="),
            "{uri}: the environment is in the export"
        );
        assert!(exported.len() < 100_000, "{uri}: {} bytes", exported.len());
    }
}

#[test]
fn buffers_outside_the_puppets_folder_are_refused_and_sizes_are_bounded() {
    for uri in [
        "../secret.txt",
        "/dev/zero",
        "/proc/self/environ",
        "link-to-dev-zero",
    ] {
        let mut scene = Scene::new("buffer");
        #[cfg(unix)]
        std::os::unix::fs::symlink("/dev/zero", scene.puppet_dir.join("link-to-dev-zero")).unwrap();
        scene.json["buffers"] = json!([{"uri": uri, "byteLength": 1_000_000}]);
        let err = Puppet::load(&scene.write()).unwrap_err().to_string();
        assert!(
            err.contains("buffer 0") && err.contains(uri),
            "{uri}: {err}"
        );
    }
    // A buffer file longer than its byteLength: only byteLength bytes are read or exported.
    let scene = Scene::new("long-buffer");
    let mut bin = std::fs::read(scene.puppet_dir.join("mesh.bin")).unwrap();
    bin.extend(std::iter::repeat_n(b'Z', 5_000_000));
    std::fs::write(scene.puppet_dir.join("mesh.bin"), &bin).unwrap();
    let exported = scene.export().unwrap();
    assert!(
        exported.len() < 100_000,
        "{} bytes exported",
        exported.len()
    );
    // A byteLength beyond what a puppet may have is refused before reading.
    let mut scene = Scene::new("huge-buffer");
    scene.json["buffers"][0]["byteLength"] = json!(u64::MAX / 2);
    let err = Puppet::load(&scene.write()).unwrap_err().to_string();
    assert!(err.contains("buffer 0"), "{err}");
}

#[test]
fn only_images_that_a_texture_shows_and_that_are_images_travel_with_an_export() {
    // A real texture beside the puppet travels (embedded).
    let scene = Scene::new("texture").with_texture("skin%20tone.png");
    let png = png_bytes([200, 120, 90]);
    std::fs::write(scene.puppet_dir.join("skin tone.png"), &png).unwrap();
    let exported = scene.export().unwrap();
    assert!(contains(&exported, &png), "the texture is not embedded");
    let puppet = Puppet::load(&scene.write()).unwrap();
    assert_eq!(puppet.images[0].pixels[..3], [200, 120, 90]);

    // A file inside the folder that no texture uses does not.
    let mut scene = Scene::new("unused");
    std::fs::write(scene.puppet_dir.join("private.png"), png_bytes([1, 2, 3])).unwrap();
    std::fs::write(scene.puppet_dir.join("notes.txt"), SECRET).unwrap();
    scene.json["images"] = json!([{"uri": "private.png"}, {"uri": "notes.txt"}]);
    let exported = scene.export().unwrap();
    assert!(
        !contains(&exported, &png_bytes([1, 2, 3])),
        "an unused image travelled"
    );
    assert!(!contains(&exported, SECRET), "an unused file travelled");

    // A texture that is not an image does not either.
    let scene = Scene::new("not-image").with_texture("notes.txt");
    std::fs::write(scene.puppet_dir.join("notes.txt"), SECRET).unwrap();
    let exported = scene.export().unwrap();
    assert!(
        !contains(&exported, SECRET),
        "a non-image texture travelled"
    );
}

#[test]
fn re_exporting_an_export_replaces_its_animation() {
    let scene = Scene::new("reexport");
    let first = scene.export().unwrap();
    let again = Scene::new("reexport-2");
    std::fs::write(again.puppet_dir.join("hostile.glb"), &first).unwrap();
    let puppet = Puppet::load(&again.puppet_dir.join("hostile.glb")).unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    let tracks = Tracks {
        frames: (0..2)
            .map(|k| TrackedFrame {
                time_s: k as f32,
                arkit: [0.5; NUM_ARKIT],
                rotation_deg: None,
            })
            .collect(),
        ..Tracks::default()
    };
    let out = again.dir.join("again.glb");
    write_animation_glb(&puppet, &r, &retarget_clip(&r, &tracks), &out).unwrap();
    let (json, _) = glb_parts(&std::fs::read(&out).unwrap());
    let names: Vec<&str> = json["animations"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|a| a["name"].as_str())
        .collect();
    assert_eq!(names, vec![ANIMATION_NAME]);
    assert_eq!(json["buffers"].as_array().unwrap().len(), 1);
}

#[test]
fn vrm_expressions_that_move_nothing_are_not_reported_as_mapped() {
    // Expressions with no binds on a model whose mesh has no morph targets.
    let vrm = json!({"VRMC_vrm": {"specVersion": "1.0", "expressions": {"preset": {
        "happy": {}, "aa": {"morphTargetBinds": []}, "blink": {"morphTargetBinds": []}
    }}}});
    let bytes = tiny_puppet(&[], Naming::Extras, Some(vrm));
    let puppet = load_detecting_panics(&bytes, None).unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert!(r.report.mapped.is_empty(), "{:?}", r.report.mapped);
    assert!(!r.report.drives_anything());
    let text = r.report.to_string();
    assert!(text.starts_with("mapped 0 channel(s)"), "{text}");
    assert!(text.contains("moving nothing"), "{text}");
}

#[test]
fn clips_made_in_code_with_impossible_times_are_refused_by_the_export() {
    let scene = Scene::new("clip-times");
    let path = scene.write();
    let puppet = Puppet::load(&path).unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    let frame = |time_s: f32| TrackedFrame {
        time_s,
        arkit: [0.5; NUM_ARKIT],
        rotation_deg: Some([1.0, 2.0, 3.0]),
    };
    let out = scene.dir.join("bad.glb");
    for times in [
        vec![0.0, f32::NAN],
        vec![0.0, f32::INFINITY],
        vec![1.0, 0.5],
        vec![0.0, 0.0],
        vec![f32::MAX, 0.0],
    ] {
        let tracks = Tracks {
            frames: times.iter().map(|&t| frame(t)).collect(),
            ..Tracks::default()
        };
        let err = write_animation_glb(&puppet, &r, &retarget_clip(&r, &tracks), &out)
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("frame 1") && err.starts_with("cannot write"),
            "{times:?}: {err}"
        );
        assert!(!out.exists(), "{times:?}: a file was written");
    }
}

#[test]
fn what_the_fuzzer_found_in_the_loader_and_the_driver_is_handled() {
    // A GLB header declaring fewer bytes than itself (the `gltf` crate subtracted its size
    // unchecked).
    let good = tiny_puppet(&names(1), Naming::Extras, None);
    for declared in [0u32, 11, 12, 19] {
        let mut bytes = good.clone();
        bytes[8..12].copy_from_slice(&declared.to_le_bytes());
        let err = load_detecting_panics(&bytes, None).unwrap_err();
        assert!(err.contains("header declares"), "{declared}: {err}");
    }
    // The head's parent scaled to zero: no rotation to turn in, the head stays at rest.
    let (mut json, bin) = glb_parts(&good);
    json["nodes"][0]["name"] = json!("Head");
    json["nodes"][1]["scale"] = json!([0.0, 0.0, 0.0]);
    let puppet = load_detecting_panics(&glb_from(&json, bin), None).unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    let pose = r.pose(&[0.5; NUM_ARKIT], Some([10.0, 5.0, -3.0]));
    let (_, q) = pose.head.expect("the head is driven");
    assert!(q.is_finite(), "{q:?}");
    // A head gain so large that gain x angle is no longer a rotation is refused.
    let mut mapping = MappingData::default();
    mapping.head.gain = 1e38;
    let err = mapping
        .validate(std::path::Path::new("x.mapping.json"))
        .unwrap_err()
        .to_string();
    assert!(err.contains("head.gain"), "{err}");
    mapping.head.gain = 10.0;
    assert!(
        mapping
            .validate(std::path::Path::new("x.mapping.json"))
            .is_ok()
    );
}

#[test]
fn the_files_a_puppet_names_are_listed_as_the_loader_resolves_them() {
    let mut scene = Scene::new("names").with_texture("tex%20ture.png");
    let buffers = scene.json["buffers"].as_array_mut().unwrap();
    buffers.push(json!({"uri": "data:application/octet-stream;base64,AAAA", "byteLength": 3}));
    buffers.push(json!({"uri": "../secret.txt", "byteLength": 3}));
    buffers.push(json!({"uri": "/etc/passwd", "byteLength": 3}));
    buffers.push(json!({"uri": "sub/./more.bin", "byteLength": 3}));
    let path = scene.write();
    let named = retarget::puppet::external_files(&path);
    let expected = vec![
        (
            "buffer 0 (mesh.bin)".to_owned(),
            scene.puppet_dir.join("mesh.bin"),
        ),
        (
            "buffer 4 (sub/./more.bin)".to_owned(),
            scene.puppet_dir.join("sub").join("more.bin"),
        ),
        (
            "image 0 (tex%20ture.png)".to_owned(),
            scene.puppet_dir.join("tex ture.png"),
        ),
    ];
    assert_eq!(named, expected);
    // A GLB names what its JSON chunk names; a file that is not a puppet names nothing.
    let glb = glb_from(&scene.json, Vec::new());
    let glb_path = scene.puppet_dir.join("named.glb");
    std::fs::write(&glb_path, glb).unwrap();
    assert_eq!(retarget::puppet::external_files(&glb_path), expected);
    std::fs::write(&glb_path, b"not a puppet").unwrap();
    assert!(retarget::puppet::external_files(&glb_path).is_empty());
    assert!(retarget::puppet::external_files(&scene.puppet_dir.join("missing.gltf")).is_empty());
}
