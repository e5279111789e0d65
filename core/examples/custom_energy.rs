//! A new bending energy declared with the derive macro, composed with a built-in one in a single geometric
//! pass, evaluated on a small mesh: prints the energy of each term, of the sum, and the gradient norm.
//!
//! Run with `cargo run --release -p hinge-core --example custom_energy`.

use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::psi::TanBending;
use hinge_core::{HingeEnergy, grid};

/// A "soft-hinge" energy: quadratic for small bends, growing only logarithmically for large ones.
#[derive(Debug, Clone, HingeEnergy)]
#[psi(k * a * (1.0 + ((theta - theta_bar) / w).powi(2)).ln())]
pub struct SoftHinge {
    /// Stiffness.
    pub k: f64,
    /// Angle scale where the energy turns from quadratic to logarithmic.
    pub w: f64,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let rest = grid::grid(20, 20, 1.0, 1.0, grid::Diagonal::Alternating)?;
    let bent = grid::wave(rest.positions());
    let soft = SoftHinge { k: 2.0, w: 0.05 };
    let tan = TanBending { k: 0.5 };
    let energy = |e: f64, g: &[f64]| (e, g.iter().map(|v| v * v).sum::<f64>().sqrt());
    for (name, (e, g)) in [
        ("soft hinge", {
            let m = BendingModel::new(&rest, soft.clone())?;
            let r = m.evaluate(
                &bent,
                Request::GRADIENT,
                Method::Refactored,
                Parallelism::Rayon,
            )?;
            energy(r.energy, &r.gradient)
        }),
        ("tan bending", {
            let m = BendingModel::new(&rest, tan.clone())?;
            let r = m.evaluate(
                &bent,
                Request::GRADIENT,
                Method::Refactored,
                Parallelism::Rayon,
            )?;
            energy(r.energy, &r.gradient)
        }),
        ("both, one pass", {
            // A tuple composes ψ terms: one geometric pass, ψ′ and ψ″ summed per hinge.
            let m = BendingModel::new(&rest, (soft, tan))?;
            let r = m.evaluate(&bent, Request::ALL, Method::Refactored, Parallelism::Rayon)?;
            energy(r.energy, &r.gradient)
        }),
    ] {
        println!("{name:>15}: energy {e:.6e}   |gradient| {g:.6e}");
    }
    Ok(())
}
