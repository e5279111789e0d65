//! A square cloth hanging over a sphere: StVK membrane, tan bending with viscous damping (one geometric
//! pass), gravity and sphere contact, composed into one `System` and evaluated; prints each term's energy,
//! the total, the gradient norm and the size of the shared sparse Hessian.
//!
//! Run with `cargo run --release -p hinge-energies --example compose`.

use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid;
use hinge_core::nalgebra::Vector3;
use hinge_energies::bending::{TanBending, ViscousDamping, stiffness_from_material};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A 1 m × 1 m cloth, 40 × 40 cells, centred over a sphere of radius 0.3 m.
    let rest = grid::grid(40, 40, 1.0, 1.0, grid::Diagonal::Alternating)?;
    let draped: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| {
            let (x, y) = (p.x - 0.5, p.y - 0.5);
            Vector3::new(x, y, 0.302 - 0.4 * (x * x + y * y))
        })
        .collect();
    let previous: Vec<Vector3<f64>> = draped
        .iter()
        .map(|p| p + Vector3::new(0.0, 0.0, 0.002))
        .collect();
    let n = rest.n_vertices();
    let (young, poisson, thickness) = (5e5, 0.3, 5e-4);
    let k_bend = stiffness_from_material(young, thickness, poisson);
    let bending = BendingModel::new(
        &rest,
        (
            TanBending { k: k_bend },
            ViscousDamping { kd: 0.1 * k_bend },
        ),
    )?;
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(StvkMembrane::new(&rest, young, poisson, thickness)?),
        Box::new(HingeTerm::new(
            "tan bending + damping",
            bending,
            Method::Refactored,
        )),
        Box::new(Gravity::new(
            lumped_masses(&rest, 0.2),
            Vector3::new(0.0, 0.0, -9.81),
        )?),
        Box::new(Contact::new(
            n,
            Obstacle::Sphere {
                center: Vector3::new(0.0, 0.0, 0.0),
                radius: 0.3,
            },
            1e4,
            0.005,
        )?),
    ];
    let mut system = System::new(n, terms)?;
    system.begin_step(&previous, 1.0 / 60.0)?;
    let e = system.evaluate(&draped, Request::ALL, Parallelism::Rayon)?;
    for (name, energy) in system.term_names().iter().zip(&e.terms) {
        println!("{name:>22}: {energy:+.6e} J");
    }
    println!("{:>22}: {:+.6e} J", "total", e.energy);
    let g: f64 = e.gradient.iter().map(|v| v * v).sum::<f64>().sqrt();
    println!(
        "|gradient| = {g:.6e} N, Hessian: {} stored entries (lower triangle)",
        system.pattern().nnz()
    );
    Ok(())
}
