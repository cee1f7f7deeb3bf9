//! The inference backends behind one trait: ONNX Runtime (through `ort`, its library loaded
//! at run time) and tract (pure Rust, for wasm32 and as the fallback when no ONNX Runtime
//! library is found).
//!
//! Every network Likeness runs has exactly one float input, so the trait takes one tensor
//! and returns the outputs in the model's declared order.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::error::{Result, TrackingError};

/// A dense row-major f32 tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Tensor {
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Result<Self> {
        let n: usize = shape.iter().product();
        if n != data.len() {
            return Err(TrackingError::InvalidInput(format!(
                "tensor of shape {shape:?} needs {n} values, got {}",
                data.len()
            )));
        }
        Ok(Self { shape, data })
    }

    pub fn zeros(shape: Vec<usize>) -> Self {
        let n = shape.iter().product();
        Self {
            shape,
            data: vec![0.0; n],
        }
    }

    pub fn is_finite(&self) -> bool {
        self.data.iter().all(|v| v.is_finite())
    }

    /// Elements per index of the leading axis.
    pub fn stride0(&self) -> usize {
        self.shape.iter().skip(1).product()
    }
}

/// Which engine runs a network.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BackendKind {
    /// ONNX Runtime through `ort` (native only).
    OnnxRuntime,
    /// tract, pure Rust (native and wasm32).
    Tract,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::OnnxRuntime => "onnxruntime",
            Self::Tract => "tract",
        }
    }
}

impl std::fmt::Display for BackendKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for BackendKind {
    type Err = TrackingError;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "onnxruntime" | "ort" => Ok(Self::OnnxRuntime),
            "tract" => Ok(Self::Tract),
            other => Err(TrackingError::InvalidInput(format!(
                "unknown backend `{other}` (use onnxruntime or tract)"
            ))),
        }
    }
}

/// What the caller asks for: a specific engine, or the fastest available one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BackendChoice {
    /// ONNX Runtime when its library loads, else tract.
    #[default]
    Auto,
    Only(BackendKind),
}

impl BackendChoice {
    /// The engine this choice resolves to on this machine.
    pub fn resolve(self) -> Result<BackendKind> {
        match self {
            Self::Only(BackendKind::OnnxRuntime) => {
                onnxruntime_status().map(|_| BackendKind::OnnxRuntime)
            }
            Self::Only(BackendKind::Tract) => Ok(BackendKind::Tract),
            Self::Auto => Ok(if onnxruntime_status().is_ok() {
                BackendKind::OnnxRuntime
            } else {
                BackendKind::Tract
            }),
        }
    }
}

impl std::str::FromStr for BackendChoice {
    type Err = TrackingError;
    fn from_str(s: &str) -> Result<Self> {
        if s.eq_ignore_ascii_case("auto") {
            Ok(Self::Auto)
        } else {
            s.parse().map(Self::Only)
        }
    }
}

/// A loaded network.
pub trait InferenceBackend: Send {
    fn kind(&self) -> BackendKind;
    /// Runs the network on its one input; outputs in the model's order.
    fn run(&mut self, input: &Tensor) -> Result<Vec<Tensor>>;
}

/// Loads `path` with `kind`. `threads` is the intra-op thread count (ONNX Runtime only;
/// tract runs on the calling thread).
pub fn load_model(
    path: &Path,
    kind: BackendKind,
    threads: usize,
) -> Result<Box<dyn InferenceBackend>> {
    if !path.is_file() {
        return Err(TrackingError::MissingModel {
            path: path.to_owned(),
            hint: "no such file".into(),
        });
    }
    match kind {
        BackendKind::Tract => Ok(Box::new(TractModel::load(path)?)),
        #[cfg(all(feature = "onnxruntime", not(target_arch = "wasm32")))]
        BackendKind::OnnxRuntime => Ok(Box::new(ort_backend::OrtModel::load(path, threads)?)),
        #[cfg(not(all(feature = "onnxruntime", not(target_arch = "wasm32"))))]
        BackendKind::OnnxRuntime => {
            let _ = threads;
            Err(TrackingError::Runtime(
                "this build has no ONNX Runtime support (feature `onnxruntime`)".into(),
            ))
        }
    }
}

fn model_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

// --- tract -----------------------------------------------------------------------------

type TractPlan = Arc<tract_onnx::prelude::TypedRunnableModel>;

/// tract needs concrete input shapes to optimise, so one plan is kept per input shape
/// (TrackNet at batch 1, ModelNet at each N used).
pub struct TractModel {
    name: String,
    proto: tract_onnx::prelude::InferenceModel,
    plans: HashMap<Vec<usize>, TractPlan>,
}

impl TractModel {
    pub fn load(path: &Path) -> Result<Self> {
        use tract_onnx::prelude::*;
        let name = model_name(path);
        let mut proto = tract_onnx::onnx()
            .proto_model_for_path(path)
            .map_err(|e| tract_error(&name, e))?;
        Self::from_proto(name, &mut proto)
    }

    /// Reads a model from bytes (wasm32 has no file system).
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<Self> {
        use tract_onnx::prelude::*;
        let mut proto = tract_onnx::onnx()
            .proto_model_for_read(&mut std::io::Cursor::new(bytes))
            .map_err(|e| tract_error(name, e))?;
        Self::from_proto(name.to_owned(), &mut proto)
    }

    fn from_proto(name: String, proto: &mut tract_onnx::pb::ModelProto) -> Result<Self> {
        use tract_onnx::prelude::*;
        let widened = widen_float16_weights(proto);
        if widened > 0 {
            tracing::debug!("{name}: {widened} float16 weights widened to float32 for tract");
        }
        let proto = tract_onnx::onnx()
            .model_for_proto_model(proto)
            .map_err(|e| tract_error(&name, e))?;
        Ok(Self {
            name,
            proto,
            plans: HashMap::new(),
        })
    }

    fn plan(&mut self, shape: &[usize]) -> Result<TractPlan> {
        use tract_onnx::prelude::*;
        if let Some(plan) = self.plans.get(shape) {
            return Ok(plan.clone());
        }
        let fact = InferenceFact::dt_shape(f32::datum_type(), shape);
        let plan = self
            .proto
            .clone()
            .with_input_fact(0, fact)
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| tract_error(&self.name, e))?;
        self.plans.insert(shape.to_vec(), plan.clone());
        Ok(plan)
    }
}

/// ONNX's data type numbers for the two float widths.
const ONNX_FLOAT: i32 = 1;
const ONNX_FLOAT16: i32 = 10;

/// Stores as float32 every float16 initializer that only feeds `Cast(to = float)` nodes
/// (how the exporter halves the download: `store_weights_fp16`), leaving those casts
/// float32 to float32, which tract removes. tract does not fold a cast of a constant into a
/// constant, so it would otherwise widen all the weights on every run: TrackNet took 14.0
/// against 7.7 ms a frame natively (`cargo bench -p tracking --bench pipeline`). Written
/// here because it is a rewrite of the ONNX protobuf before tract reads it, which no crate
/// offers. Returns how many initializers it widened.
pub fn widen_float16_weights(proto: &mut tract_onnx::pb::ModelProto) -> usize {
    use std::collections::HashMap;
    let Some(graph) = proto.graph.as_mut() else {
        return 0;
    };
    // For each tensor name, whether every node reading it is a cast to float.
    let mut only_cast_to_float: HashMap<&str, bool> = HashMap::new();
    for node in &graph.node {
        let casts_to_float = node.op_type == "Cast"
            && node
                .attribute
                .iter()
                .any(|a| a.name == "to" && a.i == i64::from(ONNX_FLOAT));
        for input in &node.input {
            let entry = only_cast_to_float.entry(input.as_str()).or_insert(true);
            *entry &= casts_to_float;
        }
    }
    let widen: Vec<bool> = graph
        .initializer
        .iter()
        .map(|t| {
            t.data_type == ONNX_FLOAT16
                && t.external_data.is_empty()
                && only_cast_to_float.get(t.name.as_str()) == Some(&true)
        })
        .collect();
    let mut widened = 0;
    for (tensor, widen) in graph.initializer.iter_mut().zip(widen) {
        if !widen {
            continue;
        }
        let halves: Vec<tract_onnx::prelude::f16> = if tensor.raw_data.is_empty() {
            // Without raw data ONNX keeps each float16's bits in an int32.
            tensor
                .int32_data
                .iter()
                .map(|&bits| tract_onnx::prelude::f16::from_bits(bits as u16))
                .collect()
        } else {
            tensor
                .raw_data
                .chunks_exact(2)
                .map(|b| tract_onnx::prelude::f16::from_le_bytes([b[0], b[1]]))
                .collect()
        };
        let count: i64 = tensor.dims.iter().product();
        if usize::try_from(count).ok() != Some(halves.len()) {
            // Not what the dims say: left for tract to report.
            continue;
        }
        tensor.raw_data = halves
            .iter()
            .flat_map(|h| h.to_f32().to_le_bytes())
            .collect();
        tensor.int32_data.clear();
        tensor.data_type = ONNX_FLOAT;
        widened += 1;
    }
    widened
}

fn tract_error(model: &str, e: impl std::fmt::Display) -> TrackingError {
    TrackingError::Inference {
        backend: "tract",
        model: model.to_owned(),
        reason: format!("{e:#}"),
    }
}

impl InferenceBackend for TractModel {
    fn kind(&self) -> BackendKind {
        BackendKind::Tract
    }

    fn run(&mut self, input: &Tensor) -> Result<Vec<Tensor>> {
        use tract_onnx::prelude::*;
        let plan = self.plan(&input.shape)?;
        let tensor = tract_onnx::prelude::Tensor::from_shape(&input.shape, &input.data)
            .map_err(|e| tract_error(&self.name, e))?;
        let outputs = plan
            .run(tvec!(tensor.into_tvalue()))
            .map_err(|e| tract_error(&self.name, e))?;
        outputs
            .iter()
            .map(|o| {
                let view = o
                    .to_plain_array_view::<f32>()
                    .map_err(|e| tract_error(&self.name, e))?;
                Ok(crate::backend::Tensor {
                    shape: view.shape().to_vec(),
                    data: view.iter().copied().collect(),
                })
            })
            .collect()
    }
}

// --- ONNX Runtime ----------------------------------------------------------------------

/// The library file name ONNX Runtime's PyPI wheel ships for the version `ort` wraps.
pub const ONNXRUNTIME_VERSION: &str = "1.31.1";

/// Where the ONNX Runtime library is looked for, in order: `ORT_DYLIB_PATH`; beside the
/// executable; `.cache/onnxruntime/` of the repository (the README's setup step unpacks
/// the PyPI wheel there); the training venv's `onnxruntime/capi/`.
pub fn onnxruntime_candidates() -> Vec<PathBuf> {
    let file = format!("libonnxruntime.so.{ONNXRUNTIME_VERSION}");
    let mut out = Vec::new();
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH").filter(|p| !p.is_empty()) {
        out.push(PathBuf::from(p));
        // An explicit path is the user's choice: do not silently use another library.
        return out;
    }
    if let Some(dir) = std::env::current_exe()
        .ok()
        .and_then(|e| e.parent().map(Path::to_owned))
    {
        out.push(dir.join(&file));
    }
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    out.push(repo.join(".cache/onnxruntime").join(&file));
    if let Ok(entries) = std::fs::read_dir(repo.join("training/.venv/lib")) {
        for e in entries.flatten() {
            out.push(e.path().join("site-packages/onnxruntime/capi").join(&file));
        }
    }
    out
}

/// Whether ONNX Runtime is usable in this process (it is loaded once, at the first call).
pub fn onnxruntime_status() -> Result<()> {
    #[cfg(all(feature = "onnxruntime", not(target_arch = "wasm32")))]
    {
        ort_backend::environment().map(|_| ())
    }
    #[cfg(not(all(feature = "onnxruntime", not(target_arch = "wasm32"))))]
    {
        Err(TrackingError::Runtime(
            "this build has no ONNX Runtime support (feature `onnxruntime`)".into(),
        ))
    }
}

#[cfg(all(feature = "onnxruntime", not(target_arch = "wasm32")))]
mod ort_backend {
    use std::path::Path;
    use std::sync::OnceLock;

    use ort::session::Session;
    use ort::session::builder::GraphOptimizationLevel;
    use ort::value::TensorRef;

    use super::{BackendKind, InferenceBackend, Tensor, model_name, onnxruntime_candidates};
    use crate::error::{Result, TrackingError};

    static ENVIRONMENT: OnceLock<std::result::Result<ort::environment::Environment, String>> =
        OnceLock::new();

    /// The process-wide ONNX Runtime environment. `ort` panics if any of its APIs is used
    /// before a library is loaded, so every use goes through here first.
    pub fn environment() -> Result<&'static ort::environment::Environment> {
        ENVIRONMENT
            .get_or_init(|| {
                let candidates = onnxruntime_candidates();
                let Some(path) = candidates.iter().find(|p| p.is_file()) else {
                    return Err(format!(
                        "no libonnxruntime.so.{} found (looked at {}); run scripts/setup.sh or set ORT_DYLIB_PATH",
                        super::ONNXRUNTIME_VERSION,
                        candidates
                            .iter()
                            .map(|p| p.display().to_string())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ));
                };
                let builder = ort::init_from(path)
                    .map_err(|e| format!("cannot load {}: {e}", path.display()))?;
                builder
                    .with_name("likeness")
                    .build()
                    .map_err(|e| format!("cannot start ONNX Runtime from {}: {e}", path.display()))
            })
            .as_ref()
            .map_err(|e| TrackingError::Runtime(e.clone()))
    }

    pub struct OrtModel {
        name: String,
        session: Session,
    }

    fn ort_error(model: &str, e: impl std::fmt::Display) -> TrackingError {
        TrackingError::Inference {
            backend: "onnxruntime",
            model: model.to_owned(),
            reason: e.to_string(),
        }
    }

    impl OrtModel {
        pub fn load(path: &Path, threads: usize) -> Result<Self> {
            let env = environment()?;
            let name = model_name(path);
            let session = Session::builder(env)
                .and_then(|b| {
                    b.with_optimization_level(GraphOptimizationLevel::All)
                        .map_err(Into::into)
                })
                .and_then(|b| b.with_intra_threads(threads.max(1)).map_err(Into::into))
                .and_then(|b| b.with_inter_threads(1).map_err(Into::into))
                // Spinning worker threads would keep a core busy between runs, slowing the
                // Rust stages in between and the ffmpeg decoder on a 2-core machine.
                .and_then(|b| b.with_intra_op_spinning(false).map_err(Into::into))
                .and_then(|mut b| b.commit_from_file(path))
                .map_err(|e| ort_error(&name, e))?;
            Ok(Self { name, session })
        }
    }

    impl InferenceBackend for OrtModel {
        fn kind(&self) -> BackendKind {
            BackendKind::OnnxRuntime
        }

        fn run(&mut self, input: &Tensor) -> Result<Vec<Tensor>> {
            let value = TensorRef::from_array_view((input.shape.clone(), input.data.as_slice()))
                .map_err(|e| ort_error(&self.name, e))?;
            let outputs = self
                .session
                .run(ort::inputs![value])
                .map_err(|e| ort_error(&self.name, e))?;
            let mut out = Vec::with_capacity(outputs.len());
            for (_, v) in outputs.iter() {
                let (shape, data) = v
                    .try_extract_tensor::<f32>()
                    .map_err(|e| ort_error(&self.name, e))?;
                out.push(Tensor {
                    shape: shape.iter().map(|&d| d.max(0) as usize).collect(),
                    data: data.to_vec(),
                });
            }
            Ok(out)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tract_onnx::pb::{AttributeProto, GraphProto, ModelProto, NodeProto, TensorProto};
    use tract_onnx::prelude::f16;

    fn half_tensor(name: &str, values: &[f32], raw: bool) -> TensorProto {
        let halves: Vec<f16> = values.iter().map(|&v| f16::from_f32(v)).collect();
        TensorProto {
            name: name.into(),
            dims: vec![values.len() as i64],
            data_type: ONNX_FLOAT16,
            raw_data: if raw {
                halves.iter().flat_map(|h| h.to_le_bytes()).collect()
            } else {
                Vec::new()
            },
            int32_data: if raw {
                Vec::new()
            } else {
                halves.iter().map(|h| i32::from(h.to_bits())).collect()
            },
            ..TensorProto::default()
        }
    }

    fn node(op: &str, input: &str, to: Option<i32>) -> NodeProto {
        NodeProto {
            op_type: op.into(),
            input: vec![input.into()],
            output: vec![format!("{input}_out")],
            attribute: to
                .map(|t| AttributeProto {
                    name: "to".into(),
                    i: i64::from(t),
                    ..AttributeProto::default()
                })
                .into_iter()
                .collect(),
            ..NodeProto::default()
        }
    }

    fn floats(t: &TensorProto) -> Vec<f32> {
        t.raw_data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect()
    }

    /// Only float16 weights read by nothing but casts to float become float32, with the
    /// same values (exact: every float16 is a float32), from raw bytes or int32 bits.
    #[test]
    fn float16_weights_that_only_feed_casts_to_float_are_widened() {
        let mut proto = ModelProto {
            graph: Some(GraphProto {
                initializer: vec![
                    half_tensor("raw", &[1.5, -2.0, 0.000_061_035_156], true),
                    half_tensor("bits", &[65504.0, -0.25], false),
                    half_tensor("also_added", &[1.0], true),
                    half_tensor("cast_to_double", &[1.0], true),
                ],
                node: vec![
                    node("Cast", "raw", Some(ONNX_FLOAT)),
                    node("Cast", "bits", Some(ONNX_FLOAT)),
                    node("Cast", "also_added", Some(ONNX_FLOAT)),
                    node("Add", "also_added", None),
                    node("Cast", "cast_to_double", Some(11)),
                ],
                ..GraphProto::default()
            }),
            ..ModelProto::default()
        };
        assert_eq!(widen_float16_weights(&mut proto), 2);
        let graph = proto.graph.as_ref().expect("graph");
        let [raw, bits, added, double] = &graph.initializer[..] else {
            panic!("four initializers");
        };
        assert_eq!((raw.data_type, bits.data_type), (ONNX_FLOAT, ONNX_FLOAT));
        assert_eq!(floats(raw), vec![1.5, -2.0, 0.000_061_035_156]);
        assert_eq!(floats(bits), vec![65504.0, -0.25]);
        assert!(bits.int32_data.is_empty());
        assert_eq!(
            (added.data_type, double.data_type),
            (ONNX_FLOAT16, ONNX_FLOAT16)
        );
        // A model without a graph is left alone.
        assert_eq!(widen_float16_weights(&mut ModelProto::default()), 0);
    }
}
