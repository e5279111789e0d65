//! Membrane locking (lecture, Euler's formula): a triangle mesh has #edges = 3#vertices − 3 − #boundary
//! edges, so stiff in-plane springs nearly fix every edge length and leave a sheet few isometric motions.
//! With no bending energy at all, a sheet folds freely along a line of mesh edges (an exact isometry) but
//! resists a fold across its triangles, which must stretch edges. Shown for mass springs, the StVK
//! membrane and the co-rotational membrane; the figures are printed.

use hinge_core::TriMesh;
use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Energy, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::{Rotation3, Unit, Vector3};
use hinge_energies::corotational::CorotationalMembrane;
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::pins::Pins;
use hinge_energies::spring::MassSpring;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{Newton, NewtonParams};

const CELLS: usize = 8;

/// The least energy of a 90° fold about the line through the sheet's centre along `direction` (in the
/// sheet's plane): vertices farther than 1.5 cells from the line are pinned at the rigidly folded
/// positions, the band around it relaxes (Newton statics).
fn fold_energy(rest: &TriMesh, energy: Box<dyn Energy>, direction: Vector3<f64>) -> (f64, usize) {
    let h = 1.0 / CELLS as f64;
    let n = rest.n_vertices();
    let d = direction.normalize();
    let normal = Vector3::z().cross(&d);
    let rotation = Rotation3::from_axis_angle(&Unit::new_normalize(d), std::f64::consts::FRAC_PI_2);
    let pivot = Vector3::new(0.5, 0.5, 0.0);
    let side = |p: &Vector3<f64>| (p - pivot).dot(&normal);
    let folded: Vec<Vector3<f64>> = rest
        .positions()
        .iter()
        .map(|p| {
            if side(p) > 0.0 {
                pivot + rotation * (p - pivot)
            } else {
                *p
            }
        })
        .collect();
    let pinned: Vec<usize> = (0..n)
        .filter(|&v| side(&rest.positions()[v]).abs() >= 1.5 * h - 1e-12)
        .collect();
    let free = n - pinned.len();
    let mut sys = System::new(n, vec![energy]).unwrap();
    let pins = Pins::new(n, pinned).unwrap();
    let params = NewtonParams {
        gradient_tolerance: 1e-11,
        max_iterations: 500,
        ..NewtonParams::default()
    };
    let mut newton = Newton::new(&sys, &pins, default_solver(), params).unwrap();
    let mut x = folded;
    newton.minimize(&mut sys, &mut x, None).unwrap();
    let e = sys
        .evaluate(&x, Request::VALUE, Parallelism::Sequential)
        .unwrap()
        .energy;
    (e, free)
}

#[test]
fn in_plane_stiffness_locks_folds_across_triangles_but_not_along_edges() {
    let rest = grid(CELLS, CELLS, 1.0, 1.0, Diagonal::Forward).unwrap();
    let n = rest.n_vertices();
    let boundary = 4 * CELLS;
    let edges = hinge_core::Topology::new(n, rest.triangles())
        .unwrap()
        .edges()
        .len();
    println!(
        "Euler's formula: {edges} edges = 3·{n} − 3 − {boundary} boundary edges = {}",
        3 * n - 3 - boundary
    );
    assert_eq!(edges, 3 * n - 3 - boundary);
    let k = 1e3;
    for (name, make) in [
        (
            "mass springs",
            Box::new(|r: &TriMesh| Box::new(MassSpring::new(r, k).unwrap()) as Box<dyn Energy>)
                as Box<dyn Fn(&TriMesh) -> Box<dyn Energy>>,
        ),
        (
            "StVK membrane",
            Box::new(|r: &TriMesh| {
                Box::new(StvkMembrane::new(r, 1e6, 0.3, 1e-3).unwrap()) as Box<dyn Energy>
            }),
        ),
        (
            "co-rotational membrane",
            Box::new(|r: &TriMesh| {
                Box::new(CorotationalMembrane::from_material(r, 1e6, 0.3, 1e-3).unwrap())
                    as Box<dyn Energy>
            }),
        ),
    ] {
        // Along the diagonal y = x (the grid's diagonals make it a line of mesh edges), and along the other
        // diagonal, which crosses every triangle it meets and has no line of mesh edges parallel to it.
        let (along, free_a) = fold_energy(&rest, make(&rest), Vector3::new(1.0, 1.0, 0.0));
        let (across, free_c) = fold_energy(&rest, make(&rest), Vector3::new(1.0, -1.0, 0.0));
        println!(
            "{name}: 90° fold along mesh edges: least energy {along:.3e} J ({free_a} free vertices); across the triangles: {across:.3e} J ({free_c} free vertices)"
        );
        assert!(along.abs() < 1e-12, "{name}: {along}");
        assert!(across > 1e-3, "{name}: {across}");
    }
}
