//! Statics: the equilibrium of a pinned shell under gravity. A 0.4 m × 0.4 m aluminium-like sheet
//! (Y = 70 GPa, h = 1 mm, ν = 0.3) is clamped along one edge (two vertex columns pinned) and sags under its
//! weight. Energies: tan bending with the plate-consistent stiffness + StVK membrane + gravity; Newton with
//! the pins eliminated. Prints iterations, residual and the free edge's deflection next to the linear
//! plate formula `w = q L⁴ / (8D)`.
//!
//! Run with `cargo run --release -p hinge-solver --example statics`.

use hinge_core::bending::{BendingModel, Method};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::Vector3;
use hinge_energies::bending::{TanBending, plate_consistent_stiffness};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::pins::Pins;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{Newton, NewtonParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (young, h, nu, rho) = (7e10, 1e-3, 0.3, 2700.0);
    // Cells twice as long as wide: hinge energies on square cells are ≈ 25% softer than the plate (README).
    let (cells_x, cells_y, length, width) = (20, 40, 0.4, 0.4);
    let rest = grid(cells_x, cells_y, length, width, Diagonal::Alternating)?;
    let n = rest.n_vertices();
    let masses = lumped_masses(&rest, rho * h);
    let k = plate_consistent_stiffness(young, h, nu);
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, TanBending { k })?,
            Method::Refactored,
        )),
        Box::new(StvkMembrane::new(&rest, young, nu, h)?),
        Box::new(Gravity::new(masses, Vector3::new(0.0, 0.0, -9.81))?),
    ];
    let mut system = System::new(n, terms)?;
    // Clamp: the first two vertex columns.
    let pinned: Vec<usize> = (0..n).filter(|v| v % (cells_x + 1) < 2).collect();
    let pins = Pins::new(n, pinned)?;
    let params = NewtonParams {
        gradient_tolerance: 1e-9,
        max_iterations: 200,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&system, &pins, default_solver(), params)?;
    let mut x = rest.positions().to_vec();
    let stats = newton.minimize(&mut system, &mut x, None)?;
    let far: Vec<usize> = (0..n).filter(|v| v % (cells_x + 1) == cells_x).collect();
    let w = -far.iter().map(|&v| x[v].z).sum::<f64>() / far.len() as f64;
    let d = young * h.powi(3) / (12.0 * (1.0 - nu * nu));
    let l = length * (1.0 - 1.0 / cells_x as f64);
    let theory = rho * h * 9.81 * l.powi(4) / (8.0 * d);
    println!(
        "{} Newton iterations, final ‖∇E‖ = {:.2e}",
        stats.iterations,
        stats.gradient_norms.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "free edge deflection {w:.4e} m; plate formula {theory:.4e} m (ratio {:.3})",
        w / theory
    );
    Ok(())
}
