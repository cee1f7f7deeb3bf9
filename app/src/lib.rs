//! # likeness: the studio and command-line tool
//!
//! Wires the crates together: loads the face model (`face`), draws it (`renderer`) and
//! shows it in an egui window or writes the same views to files. It owns the user-facing
//! behaviour (flags, messages, the scripted demo) and none of the model's mathematics,
//! which live in `face`.

pub mod background;
pub mod blendshape_panel;
pub mod colormap;
pub mod demo;
pub mod fixture;
pub mod footage;
pub mod fps_probe;
#[cfg(not(target_arch = "wasm32"))]
pub mod frame_damage;
pub mod gpu_view;
#[cfg(not(target_arch = "wasm32"))]
pub mod headless;
pub mod motion_panel;
pub mod notices;
pub mod overlay_view;
pub mod puppet_panel;
pub mod puppet_view;
#[cfg(not(target_arch = "wasm32"))]
pub mod retarget_cli;
pub mod scene;
pub mod settings;
#[cfg(not(target_arch = "wasm32"))]
pub mod soft_window;
pub mod stepped;
pub mod studio;
pub mod studio_panels;
pub mod studio_session;
#[cfg(not(target_arch = "wasm32"))]
pub mod studio_shots;
#[cfg(not(target_arch = "wasm32"))]
pub mod track_cli;
pub mod uv_panel;
pub mod web_host;
