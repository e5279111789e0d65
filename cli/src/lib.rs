//! The library side of the `hinge` binary: scene files (TOML and the built-in scenes) and their simulation,
//! for other front ends (the Python package runs scenes through it).

pub mod checkpoint;
pub mod files;
pub mod fit;
pub mod limits;
pub mod run;
pub mod scene;
pub mod view;
