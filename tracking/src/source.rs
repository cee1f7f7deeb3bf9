//! Footage: a single image, a folder of images, a video file or a live camera, as a
//! stream of RGB frames with timestamps.
//!
//! Video files and cameras are decoded by the `ffmpeg` command-line program (Debian's
//! `ffmpeg` package, installed by `scripts/setup.sh`), read as raw RGB frames from its
//! standard output. A subprocess rather than FFmpeg bindings: no C headers, clang or
//! version-matched libav at build time, and a crashing decoder cannot take the tracker
//! down with it. A camera is the same pipe with a capture device as its input (`v4l2` on
//! Linux), so the live path is tested with FFmpeg's own virtual sources (`lavfi`).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::time::Instant;

use image::RgbImage;

use crate::error::{Result, TrackingError, io_error};

/// Frames larger than this (in pixels) are refused: a tracker needs a face of a few hundred
/// pixels, and a 100-megapixel frame would only exhaust memory.
pub const MAX_FRAME_PIXELS: u64 = 50_000_000;
/// Longest side accepted for a frame.
pub const MAX_FRAME_SIDE: u32 = 16_384;

/// File extensions read as still images.
pub const IMAGE_EXTENSIONS: &[&str] = &["png", "jpg", "jpeg", "bmp", "webp", "tif", "tiff"];

/// One decoded frame.
#[derive(Clone, Debug)]
pub struct Frame {
    pub index: usize,
    pub time_s: f64,
    pub image: RgbImage,
    /// The file it came from (image inputs).
    pub path: Option<PathBuf>,
}

/// A frame that could not be decoded: it becomes a "no face" record, and the footage goes
/// on.
#[derive(Debug)]
pub struct FrameError {
    pub index: usize,
    pub time_s: f64,
    pub error: TrackingError,
}

/// What the next call of [`FrameSource::next_frame`] gives.
pub enum Next {
    Frame(Frame),
    /// This frame is unreadable; later frames may still be fine.
    Skipped(FrameError),
    End,
}

/// A stream of frames.
pub trait FrameSource: Send {
    fn next_frame(&mut self) -> Result<Next>;
    /// Total frames if known in advance (for progress bars).
    fn len_hint(&self) -> Option<usize>;
    /// Frames per second (nominal for image folders and live sources).
    fn fps(&self) -> f64;
    /// A short description (file name, device) for reports.
    fn describe(&self) -> String;
    /// Whether frames arrive in real time (a camera): the tracker may drop frames.
    fn is_live(&self) -> bool {
        false
    }
}

/// What the user named as input.
#[derive(Clone, Debug, PartialEq)]
pub enum InputSpec {
    Image(PathBuf),
    Folder(PathBuf),
    Video(PathBuf),
    /// `webcam` or `webcam:/dev/video1` (Linux v4l2 device; `avfoundation`/`dshow` names
    /// elsewhere through `ffmpeg:` below).
    Webcam(String),
    /// `ffmpeg:FORMAT:INPUT`, any FFmpeg input, e.g. `ffmpeg:lavfi:testsrc2=size=640x480:rate=30`
    /// (a virtual camera) or `ffmpeg:v4l2:/dev/video2`; read live.
    FfmpegLive {
        format: String,
        input: String,
    },
}

impl InputSpec {
    /// Interprets a command-line input.
    pub fn parse(text: &str) -> Result<Self> {
        if text == "webcam" {
            return Ok(Self::Webcam(default_webcam().into()));
        }
        if let Some(device) = text.strip_prefix("webcam:") {
            return Ok(Self::Webcam(device.into()));
        }
        if let Some(rest) = text.strip_prefix("ffmpeg:") {
            let (format, input) = rest.split_once(':').ok_or_else(|| {
                TrackingError::InvalidInput(format!(
                    "`{text}`: expected ffmpeg:FORMAT:INPUT, e.g. ffmpeg:lavfi:testsrc2"
                ))
            })?;
            return Ok(Self::FfmpegLive {
                format: format.into(),
                input: input.into(),
            });
        }
        let path = PathBuf::from(text);
        if path.is_dir() {
            return Ok(Self::Folder(path));
        }
        if !path.exists() {
            return Err(TrackingError::Io {
                path,
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            });
        }
        if is_image_path(&path) {
            Ok(Self::Image(path))
        } else {
            Ok(Self::Video(path))
        }
    }

    /// Opens the source. `fps` is the frame rate given to image inputs.
    pub fn open(&self, fps: f64) -> Result<Box<dyn FrameSource>> {
        Ok(match self {
            Self::Image(p) => Box::new(ImageFiles::new(
                vec![p.clone()],
                fps,
                p.display().to_string(),
            )),
            Self::Folder(dir) => Box::new(ImageFiles::folder(dir, fps)?),
            Self::Video(p) => Box::new(FfmpegSource::video(p)?),
            Self::Webcam(device) => Box::new(FfmpegSource::live(webcam_format(), device, fps)?),
            Self::FfmpegLive { format, input } => Box::new(FfmpegSource::live(format, input, fps)?),
        })
    }

    /// Real footage needs face detection; a single image or a folder may be pre-cropped.
    pub fn is_footage(&self) -> bool {
        !matches!(self, Self::Image(_) | Self::Folder(_))
    }
}

fn default_webcam() -> &'static str {
    if cfg!(target_os = "macos") {
        "0"
    } else if cfg!(windows) {
        "video=0"
    } else {
        "/dev/video0"
    }
}

fn webcam_format() -> &'static str {
    if cfg!(target_os = "macos") {
        "avfoundation"
    } else if cfg!(windows) {
        "dshow"
    } else {
        "v4l2"
    }
}

pub fn is_image_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Decodes one image file, refusing frames above [`MAX_FRAME_PIXELS`] before allocating.
pub fn read_image(path: &Path) -> Result<RgbImage> {
    let open = || std::fs::File::open(path).map(std::io::BufReader::new);
    decode_image_with(open).map_err(|e| match e {
        ImageFailure::Read(e) => io_error(path)(e),
        ImageFailure::Decode(reason) => TrackingError::Decode {
            path: path.to_owned(),
            reason,
        },
    })
}

/// Decodes an image file's bytes (what a browser or a drop hands over) with the limits of
/// [`read_image`]; the error says why it is not a readable frame.
pub fn decode_image(bytes: &[u8]) -> std::result::Result<RgbImage, String> {
    decode_image_with(|| Ok(std::io::Cursor::new(bytes))).map_err(|e| match e {
        ImageFailure::Read(e) => e.to_string(),
        ImageFailure::Decode(reason) => reason,
    })
}

enum ImageFailure {
    Read(std::io::Error),
    Decode(String),
}

/// The decoding of [`read_image`] and [`decode_image`]: the size first (refused above the
/// limits before any pixel is allocated), then the pixels. `open` gives the data from its
/// start each time.
fn decode_image_with<R: std::io::BufRead + std::io::Seek>(
    open: impl Fn() -> std::io::Result<R>,
) -> std::result::Result<RgbImage, ImageFailure> {
    let reader = |data: R| {
        image::ImageReader::new(data)
            .with_guessed_format()
            .map_err(ImageFailure::Read)
    };
    let decode = |e: image::ImageError| ImageFailure::Decode(e.to_string());
    let (w, h) = reader(open().map_err(ImageFailure::Read)?)?
        .into_dimensions()
        .map_err(decode)?;
    check_frame_size(w, h).map_err(|e| ImageFailure::Decode(e.to_string()))?;
    let mut pixels = reader(open().map_err(ImageFailure::Read)?)?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_FRAME_SIDE);
    limits.max_image_height = Some(MAX_FRAME_SIDE);
    limits.max_alloc = Some(MAX_FRAME_PIXELS * 8);
    pixels.limits(limits);
    Ok(pixels.decode().map_err(decode)?.to_rgb8())
}

/// Refuses empty and oversized frames.
pub fn check_frame_size(w: u32, h: u32) -> Result<()> {
    if w == 0 || h == 0 {
        return Err(TrackingError::InvalidInput(format!(
            "the frame is empty ({w}x{h})"
        )));
    }
    if w > MAX_FRAME_SIDE || h > MAX_FRAME_SIDE || u64::from(w) * u64::from(h) > MAX_FRAME_PIXELS {
        return Err(TrackingError::InvalidInput(format!(
            "the frame is {w}x{h}; Likeness accepts at most {MAX_FRAME_SIDE} pixels a side and {} megapixels (downscale it first)",
            MAX_FRAME_PIXELS / 1_000_000
        )));
    }
    Ok(())
}

/// A list of image files, read lazily.
pub struct ImageFiles {
    files: Vec<PathBuf>,
    next: usize,
    fps: f64,
    name: String,
}

impl ImageFiles {
    pub fn new(files: Vec<PathBuf>, fps: f64, name: String) -> Self {
        Self {
            files,
            next: 0,
            fps: if fps.is_finite() && fps > 0.0 {
                fps
            } else {
                30.0
            },
            name,
        }
    }

    /// The images of `dir` (by extension), in natural order (`frame_2` before `frame_10`).
    pub fn folder(dir: &Path, fps: f64) -> Result<Self> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_error(dir))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && is_image_path(p))
            .collect();
        if files.is_empty() {
            return Err(TrackingError::InvalidInput(format!(
                "{} has no images ({})",
                dir.display(),
                IMAGE_EXTENSIONS.join(", ")
            )));
        }
        files.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
        Ok(Self::new(files, fps, dir.display().to_string()))
    }
}

/// Orders strings with embedded numbers by value.
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    // Runs of digits and of other characters, as slices of `s`: sorting a large folder
    // compares names O(n log n) times, so no allocation per run.
    fn chunks(s: &str) -> Vec<(bool, &str)> {
        let mut out: Vec<(bool, &str)> = Vec::new();
        let mut start = 0;
        let mut run_is_digits = None;
        for (i, c) in s.char_indices() {
            let digit = c.is_ascii_digit();
            if run_is_digits.is_some_and(|d| d != digit) {
                out.push((!digit, &s[start..i]));
                start = i;
            }
            run_is_digits = Some(digit);
        }
        if let Some(digit) = run_is_digits {
            out.push((digit, &s[start..]));
        }
        out
    }
    let (ca, cb) = (chunks(a), chunks(b));
    for ((da, ta), (db, tb)) in ca.iter().zip(&cb) {
        let ord = if *da && *db {
            let (na, nb) = (ta.trim_start_matches('0'), tb.trim_start_matches('0'));
            na.len().cmp(&nb.len()).then_with(|| na.cmp(nb))
        } else {
            ta.cmp(tb)
        };
        if ord.is_ne() {
            return ord;
        }
    }
    ca.len().cmp(&cb.len())
}

impl FrameSource for ImageFiles {
    fn next_frame(&mut self) -> Result<Next> {
        let Some(path) = self.files.get(self.next).cloned() else {
            return Ok(Next::End);
        };
        let index = self.next;
        self.next += 1;
        let time_s = index as f64 / self.fps;
        Ok(match read_image(&path) {
            Ok(image) => Next::Frame(Frame {
                index,
                time_s,
                image,
                path: Some(path),
            }),
            Err(error) => Next::Skipped(FrameError {
                index,
                time_s,
                error,
            }),
        })
    }

    fn len_hint(&self) -> Option<usize> {
        Some(self.files.len())
    }

    fn fps(&self) -> f64 {
        self.fps
    }

    fn describe(&self) -> String {
        self.name.clone()
    }
}

/// What `ffprobe` says about a video's first video stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VideoInfo {
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    pub frames: Option<usize>,
}

/// Frame rates of video files outside [`MIN_VIDEO_FPS`, `MAX_VIDEO_FPS`] are not believed
/// (the next candidate, or 30, is used).
pub const MIN_VIDEO_FPS: f64 = 0.001;
pub const MAX_VIDEO_FPS: f64 = 1000.0;

/// Reads width, height, frame rate and frame count with `ffprobe`.
pub fn probe_video(path: &Path) -> Result<VideoInfo> {
    let decode = |reason: String| TrackingError::Decode {
        path: path.to_owned(),
        reason,
    };
    let output = Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v:0", "-show_entries"])
        .arg("stream=width,height,avg_frame_rate,r_frame_rate,nb_frames")
        .args(["-of", "json"])
        .arg(path)
        .output()
        .map_err(|e| decode(ffmpeg_missing(e)))?;
    if !output.status.success() {
        let msg = String::from_utf8_lossy(&output.stderr);
        return Err(decode(format!(
            "not a readable video ({})",
            msg.lines().next().unwrap_or("ffprobe failed").trim()
        )));
    }
    parse_probe_output(&output.stdout).map_err(decode)
}

/// What `ffprobe -show_entries stream=width,height,avg_frame_rate,r_frame_rate,nb_frames
/// -of json` printed about the first video stream; the error says what is missing.
pub fn parse_probe_output(stdout: &[u8]) -> std::result::Result<VideoInfo, String> {
    let json: serde_json::Value = serde_json::from_slice(stdout).map_err(|e| e.to_string())?;
    let stream = json
        .get("streams")
        .and_then(|s| s.get(0))
        .ok_or("it has no video stream")?;
    // A size beyond u32 is refused like any oversized frame (not truncated to its low
    // bits); a missing one reads as 0, which is refused too.
    let dim = |k: &str| {
        stream
            .get(k)
            .and_then(serde_json::Value::as_u64)
            .map_or(0, |v| u32::try_from(v).unwrap_or(u32::MAX))
    };
    let (width, height) = (dim("width"), dim("height"));
    check_frame_size(width, height).map_err(|e| e.to_string())?;
    // A rate `n/d` outside the plausible range (not finite, below one frame in 1000 s or
    // above 1000 fps) is not used: every frame's time is its index divided by it.
    let rate = |k: &str| {
        stream.get(k).and_then(|v| v.as_str()).and_then(|s| {
            let (n, d) = s.split_once('/')?;
            let (n, d): (f64, f64) = (n.parse().ok()?, d.parse().ok()?);
            let fps = n / d;
            (d > 0.0 && n > 0.0 && (MIN_VIDEO_FPS..=MAX_VIDEO_FPS).contains(&fps)).then_some(fps)
        })
    };
    let fps = rate("avg_frame_rate")
        .or_else(|| rate("r_frame_rate"))
        .unwrap_or(30.0);
    let frames = stream
        .get("nb_frames")
        .and_then(|v| v.as_str())
        .and_then(|s| s.parse().ok());
    Ok(VideoInfo {
        width,
        height,
        fps,
        frames,
    })
}

fn ffmpeg_missing(e: std::io::Error) -> String {
    if e.kind() == std::io::ErrorKind::NotFound {
        "ffmpeg/ffprobe is not installed (Debian: apt-get install ffmpeg; scripts/setup.sh does it)"
            .into()
    } else {
        format!("cannot run ffmpeg: {e}")
    }
}

/// The size `ffprobe -show_entries stream=width,height -of csv=p=0` printed for a live
/// input: `width,height` on its first line.
pub fn parse_live_size(stdout: &str) -> Option<(u32, u32)> {
    let dims: Vec<u32> = stdout
        .trim()
        .lines()
        .next()
        .unwrap_or("")
        .split(',')
        .filter_map(|v| v.trim().parse().ok())
        .collect();
    match dims[..] {
        [width, height] => Some((width, height)),
        _ => None,
    }
}

/// Frames of one size from a raw RGB byte stream (`ffmpeg -f rawvideo -pix_fmt rgb24`,
/// rows top to bottom).
pub struct RawFrames<R> {
    reader: R,
    width: u32,
    height: u32,
    frame_len: usize,
}

/// What [`RawFrames::next_frame`] read.
#[derive(Debug)]
pub enum RawFrame {
    Frame(RgbImage),
    /// The stream ended (a frame cut short by its end is dropped).
    End,
}

impl<R: Read> RawFrames<R> {
    /// Frames of `width` x `height` (refused beyond [`check_frame_size`]'s limits).
    pub fn new(reader: R, width: u32, height: u32) -> Result<Self> {
        check_frame_size(width, height)?;
        Ok(Self {
            reader,
            width,
            height,
            frame_len: width as usize * height as usize * 3,
        })
    }

    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The next whole frame; reads are retried when interrupted.
    pub fn next_frame(&mut self) -> std::io::Result<RawFrame> {
        let mut buf = vec![0u8; self.frame_len];
        let mut filled = 0;
        while filled < buf.len() {
            match self.reader.read(&mut buf[filled..]) {
                Ok(0) => return Ok(RawFrame::End),
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        RgbImage::from_raw(self.width, self.height, buf)
            .map(RawFrame::Frame)
            .ok_or_else(|| std::io::Error::other("frame buffer of the wrong size"))
    }
}

/// Raw RGB frames from an `ffmpeg` child process.
pub struct FfmpegSource {
    child: Child,
    frames_in: RawFrames<ChildStdout>,
    fps: f64,
    frames: Option<usize>,
    next: usize,
    name: String,
    live_start: Option<Instant>,
    finished: bool,
}

impl FfmpegSource {
    pub fn video(path: &Path) -> Result<Self> {
        let info = probe_video(path)?;
        let mut cmd = Command::new("ffmpeg");
        cmd.args(["-nostdin", "-v", "error", "-i"]).arg(path);
        Self::spawn(
            cmd,
            info.width,
            info.height,
            info.fps,
            info.frames,
            path.display().to_string(),
            false,
        )
    }

    /// A live input (camera or virtual source) at its own size; frames are timed by the
    /// wall clock.
    pub fn live(format: &str, input: &str, fps: f64) -> Result<Self> {
        let name = format!("{format}:{input}");
        // The size of a live input is only known once it runs: probe it first.
        let probe = Command::new("ffprobe")
            .args(["-v", "error", "-f", format, "-i", input])
            .args([
                "-select_streams",
                "v:0",
                "-show_entries",
                "stream=width,height",
                "-of",
                "csv=p=0",
            ])
            .output()
            .map_err(|e| TrackingError::Decode {
                path: name.clone().into(),
                reason: ffmpeg_missing(e),
            })?;
        let size = parse_live_size(&String::from_utf8_lossy(&probe.stdout));
        let Some((width, height)) = size.filter(|_| probe.status.success()) else {
            return Err(TrackingError::Decode {
                path: name.into(),
                reason: format!(
                    "cannot open this camera or live input ({})",
                    String::from_utf8_lossy(&probe.stderr)
                        .lines()
                        .next()
                        .unwrap_or("no video stream")
                        .trim()
                ),
            });
        };
        check_frame_size(width, height)?;
        let mut cmd = Command::new("ffmpeg");
        cmd.args(["-nostdin", "-v", "error", "-f", format, "-i", input]);
        let fps = if fps.is_finite() && fps > 0.0 {
            fps
        } else {
            30.0
        };
        Self::spawn(cmd, width, height, fps, None, name, true)
    }

    fn spawn(
        mut cmd: Command,
        width: u32,
        height: u32,
        fps: f64,
        frames: Option<usize>,
        name: String,
        live: bool,
    ) -> Result<Self> {
        cmd.args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().map_err(|e| TrackingError::Decode {
            path: name.clone().into(),
            reason: ffmpeg_missing(e),
        })?;
        let stdout = child.stdout.take().ok_or_else(|| TrackingError::Decode {
            path: name.clone().into(),
            reason: "ffmpeg gave no output pipe".into(),
        })?;
        let frames_in = match RawFrames::new(stdout, width, height) {
            Ok(frames) => frames,
            Err(e) => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(e);
            }
        };
        Ok(Self {
            child,
            frames_in,
            fps,
            frames,
            next: 0,
            name,
            live_start: live.then(Instant::now),
            finished: false,
        })
    }

    pub fn size(&self) -> (u32, u32) {
        self.frames_in.size()
    }

    fn stderr_tail(&mut self) -> String {
        let mut text = String::new();
        if let Some(mut err) = self.child.stderr.take() {
            let _ = err.read_to_string(&mut text);
        }
        text.lines().rev().take(3).collect::<Vec<_>>().join(" / ")
    }
}

impl FrameSource for FfmpegSource {
    fn next_frame(&mut self) -> Result<Next> {
        if self.finished {
            return Ok(Next::End);
        }
        let image = match self.frames_in.next_frame() {
            Ok(RawFrame::Frame(image)) => image,
            Ok(RawFrame::End) => {
                self.finished = true;
                let status = self.child.wait().ok();
                let tail = self.stderr_tail();
                let failed = status.is_some_and(|s| !s.success());
                if self.next == 0 || failed {
                    return Err(TrackingError::Decode {
                        path: self.name.clone().into(),
                        reason: if self.next == 0 {
                            format!(
                                "no frame could be decoded ({})",
                                if tail.is_empty() {
                                    "empty video"
                                } else {
                                    &tail
                                }
                            )
                        } else {
                            format!("decoding stopped after {} frames ({tail})", self.next)
                        },
                    });
                }
                return Ok(Next::End);
            }
            Err(e) => {
                self.finished = true;
                return Err(TrackingError::Decode {
                    path: self.name.clone().into(),
                    reason: format!("reading frames failed: {e}"),
                });
            }
        };
        let index = self.next;
        self.next += 1;
        let time_s = match self.live_start {
            Some(start) => start.elapsed().as_secs_f64(),
            None => index as f64 / self.fps,
        };
        Ok(Next::Frame(Frame {
            index,
            time_s,
            image,
            path: None,
        }))
    }

    fn len_hint(&self) -> Option<usize> {
        self.frames
    }

    fn fps(&self) -> f64 {
        self.fps
    }

    fn describe(&self) -> String {
        self.name.clone()
    }

    fn is_live(&self) -> bool {
        self.live_start.is_some()
    }
}

impl Drop for FfmpegSource {
    fn drop(&mut self) {
        // A live source never ends on its own, and a caller may stop a video early.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
