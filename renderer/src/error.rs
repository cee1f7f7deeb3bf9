/// Everything that can go wrong in the renderer. Bad input is always reported here, never
/// by a panic, because the inputs come from models and files the renderer cannot trust.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(
        "no GPU adapter found ({0}); without a GPU, install a software Vulkan driver \
         (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers`)"
    )]
    NoAdapter(String),

    #[error("could not create the GPU device: {0}")]
    RequestDevice(String),

    #[error("inconsistent mesh data: {0}")]
    InvalidMesh(String),

    #[error("invalid albedo texture: {0}")]
    InvalidTexture(String),

    #[error("invalid blendshape weights: {0}")]
    InvalidWeights(String),

    #[error("invalid input: {0}")]
    InvalidInput(String),

    #[error(
        "{what} needs a {width}x{height} texture (x{layers} layers) but the device allows at most \
         {max_dim}x{max_dim} (x{max_layers} layers)"
    )]
    TextureTooLarge {
        what: &'static str,
        width: u32,
        height: u32,
        layers: u32,
        max_dim: u32,
        max_layers: u32,
    },

    #[error("reading the rendered image back from the GPU failed: {0}")]
    Readback(String),
}
