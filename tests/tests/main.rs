//! Every integration test of hinge-tests, one module per file, linked into one binary: one release link
//! (with thin LTO over faer and nalgebra) instead of one per file, which was most of CI's test build time.
//! Run one file's tests with a module filter:
//! `cargo test -p hinge-tests --release --test integration adjoint:: -- --nocapture`.

mod adjoint;
mod anisotropy;
mod assembly;
mod barrier;
mod corotational;
mod energies;
mod hinge_kernels;
mod locking;
mod macro_psi;
mod mesh_files;
mod moving_obstacles;
mod neohookean;
mod ordering;
mod plasticity;
mod psi_fuzz;
mod public_api;
mod runtime_psi;
mod scratch;
mod solver;
mod topology;
mod user_meshes;
