//! UV face-parsing map T. Being written.
