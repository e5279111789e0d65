//! Bring your own mesh: read an OBJ (or OFF, PLY or STL), hang it by its lowest-x vertices under gravity (tan
//! bending + StVK membrane, implicit Euler with damping), write the result in the output's format.
//!
//! Run with `cargo run --release -p hinge-solver --example obj_in_obj_out [-- INPUT.obj|.off|.ply|.stl
//! [OUTPUT.obj|.off|.ply]]`.
//! Without arguments it writes a small built-in mesh to `out/obj_in_obj_out/input.obj` and uses that.

use std::path::PathBuf;

use hinge_core::bending::{BendingModel, Method};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::meshio::{read_mesh, write_mesh};
use hinge_core::nalgebra::Vector3;
use hinge_energies::bending::{TanBending, ViscousDamping, stiffness_from_material};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::pins::Pins;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{ImplicitEuler, NewtonParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = PathBuf::from("out/obj_in_obj_out");
    std::fs::create_dir_all(&dir)?;
    let input = match args.first() {
        Some(p) => PathBuf::from(p),
        None => {
            // A 16×8 strip, written as the user's own file would be.
            let g =
                hinge_core::grid::grid(16, 8, 0.4, 0.2, hinge_core::grid::Diagonal::Alternating)?;
            let p = dir.join("input.obj");
            write_mesh(&p, g.positions(), g.triangles())?;
            p
        }
    };
    let output = args
        .get(1)
        .map_or_else(|| dir.join("output.obj"), PathBuf::from);
    let file = read_mesh(&input)?;
    if file.polygons_split > 0 {
        println!("{} polygons fan-triangulated", file.polygons_split);
    }
    let rest = file.mesh;
    let n = rest.n_vertices();
    println!(
        "{}: {n} vertices, {} triangles",
        input.display(),
        rest.n_triangles()
    );

    let (young, h, nu, density) = (1e6, 1e-3, 0.3, 0.3);
    let k = stiffness_from_material(young, h, nu);
    let masses = lumped_masses(&rest, density);
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new(
            "bending",
            BendingModel::new(&rest, (TanBending { k }, ViscousDamping { kd: 0.05 * k }))?,
            Method::Refactored,
        )),
        Box::new(StvkMembrane::new(&rest, young, nu, h)?),
        Box::new(Gravity::new(masses.clone(), Vector3::new(0.0, 0.0, -9.81))?),
    ];
    let mut system = System::new(n, terms)?;
    let xmin = rest
        .positions()
        .iter()
        .map(|p| p.x)
        .fold(f64::INFINITY, f64::min);
    let pinned: Vec<usize> = (0..n)
        .filter(|&v| rest.positions()[v].x <= xmin + 1e-9)
        .collect();
    println!("pinned {} vertices at x = {xmin}", pinned.len());
    let pins = Pins::new(n, pinned)?;
    let mut stepper = ImplicitEuler::new(
        &system,
        1.0 / 60.0,
        masses,
        pins,
        default_solver(),
        NewtonParams::default(),
    )?;
    let (mut x, mut v) = (rest.positions().to_vec(), vec![Vector3::zeros(); n]);
    let mut iterations = 0;
    for _ in 0..60 {
        iterations += stepper.step(&mut system, &mut x, &mut v)?.iterations;
    }
    write_mesh(&output, &x, rest.triangles())?;
    let lowest = x.iter().map(|p| p.z).fold(f64::INFINITY, f64::min);
    println!(
        "60 steps, {iterations} Newton iterations; lowest point z = {lowest:.4} m; wrote {}",
        output.display()
    );
    Ok(())
}
