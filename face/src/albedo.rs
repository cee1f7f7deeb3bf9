//! Procedural mean albedo R_0. Being written.
