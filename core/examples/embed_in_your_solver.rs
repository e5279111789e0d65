//! Your simulator, hinge's bending forces and Hessian: a user-owned implicit-Euler loop over *your* arrays
//! (flat `Vec<f64>` positions, `[u32; 3]` triangles, your own CSR matrix and conjugate-gradient solver).
//! hinge only evaluates: energy, gradient into your buffer, Hessian values scattered into your CSR arrays.
//!
//! A 24×24 cloth pinned along one edge falls under gravity for 30 steps. Stretching is the user's own edge
//! springs (their gradient and a PSD Hessian added into the same CSR arrays); each step takes a few Newton
//! iterations of `(M/Δt² + H) Δx = −∇F`, solved by the user's CG. Prints energy and CG iterations.
//!
//! Run with `cargo run --release -p hinge-core --example embed_in_your_solver`.

use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::export::CsrLayout;
use hinge_core::layout::Positions;
use hinge_core::psi::TanBending;

/// The user's own sparse matrix: CSR over 3n unknowns.
struct MyCsr {
    row_ptr: Vec<usize>,
    col_idx: Vec<usize>,
    values: Vec<f64>,
}

impl MyCsr {
    fn mul(&self, x: &[f64], y: &mut [f64]) {
        for (r, yr) in y.iter_mut().enumerate() {
            *yr = (self.row_ptr[r]..self.row_ptr[r + 1])
                .map(|k| self.values[k] * x[self.col_idx[k]])
                .sum();
        }
    }
}

/// The user's own Jacobi-preconditioned conjugate gradients on the free unknowns (`fixed` rows are held at 0).
fn my_cg(a: &MyCsr, diag: &[f64], b: &[f64], fixed: &[bool], x: &mut [f64]) -> usize {
    let n = b.len();
    let mask = |v: &mut [f64]| {
        for (vi, &f) in v.iter_mut().zip(fixed) {
            if f {
                *vi = 0.0;
            }
        }
    };
    x.fill(0.0);
    let mut r = b.to_vec();
    mask(&mut r);
    let mut z: Vec<f64> = r.iter().zip(diag).map(|(r, d)| r / d).collect();
    let mut p = z.clone();
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let b_norm = r.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut ap = vec![0.0; n];
    for it in 0..2000 {
        a.mul(&p, &mut ap);
        mask(&mut ap);
        let alpha = rz / p.iter().zip(&ap).map(|(a, b)| a * b).sum::<f64>();
        for i in 0..n {
            x[i] += alpha * p[i];
            r[i] -= alpha * ap[i];
        }
        if r.iter().map(|v| v * v).sum::<f64>().sqrt() <= 1e-10 * b_norm {
            return it + 1;
        }
        for i in 0..n {
            z[i] = r[i] / diag[i];
        }
        let rz_new: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        for i in 0..n {
            p[i] = z[i] + rz_new / rz * p[i];
        }
        rz = rz_new;
    }
    2000
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The user's mesh: flat coordinates and u32 triangles.
    let (nx, h) = (24usize, 1.0 / 24.0);
    let mut x: Vec<f64> = Vec::new();
    for j in 0..=nx {
        for i in 0..=nx {
            x.extend_from_slice(&[i as f64 * h, j as f64 * h, 0.0]);
        }
    }
    let id = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    let mut tris: Vec<[u32; 3]> = Vec::new();
    for j in 0..nx {
        for i in 0..nx {
            tris.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            tris.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    let n = x.len() / 3;
    let fixed: Vec<bool> = (0..3 * n).map(|d| (d / 3) % (nx + 1) == 0).collect(); // the x = 0 edge

    // hinge: rest mesh and bending model, built once; the CSR layout of its Hessian, built once.
    let rest = TriMesh::from_arrays(&x[..], &tris[..])?;
    let model = BendingModel::new(&rest, TanBending { k: 1e-3 })?;
    let layout = CsrLayout::new(model.pattern());
    let mut hessian = MyCsr {
        row_ptr: layout.row_ptr().to_vec(),
        col_idx: layout.col_idx().to_vec(),
        values: vec![0.0; layout.nnz()],
    };
    let diag_slot: Vec<usize> = (0..3 * n)
        .map(|r| {
            (hessian.row_ptr[r]..hessian.row_ptr[r + 1])
                .find(|&k| hessian.col_idx[k] == r)
                .ok_or("missing diagonal")
        })
        .collect::<Result<_, _>>()?;
    // The user's own buffers: forces/gradient (3n) and the lower-triangle Hessian values hinge fills.
    let mut grad = vec![0.0; 3 * n];
    let mut lower = vec![0.0; model.pattern().nnz()];
    let mut scratch = model.new_scratch();
    let mut bending_energy = 0.0;
    // The user's springs on the mesh edges, with their CSR slots found once (columns are sorted per row).
    let slot = |r: usize, c: usize| -> Result<usize, &'static str> {
        let row = &hessian.col_idx[hessian.row_ptr[r]..hessian.row_ptr[r + 1]];
        row.binary_search(&c)
            .map(|k| hessian.row_ptr[r] + k)
            .map_err(|_| "edge not in the pattern")
    };
    let mut edges: Vec<(usize, usize)> = tris
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b) as usize, a.max(b) as usize))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let springs: Vec<(usize, usize, f64, Vec<usize>)> = edges
        .iter()
        .map(|&(a, b)| {
            let len = (0..3)
                .map(|k| (x[3 * a + k] - x[3 * b + k]).powi(2))
                .sum::<f64>()
                .sqrt();
            // Slots of the 4 blocks (aa, ab, ba, bb), 9 entries each, row-major.
            let mut s = Vec::with_capacity(36);
            for (p, q) in [(a, a), (a, b), (b, a), (b, b)] {
                for r in 0..3 {
                    for c in 0..3 {
                        s.push(slot(3 * p + r, 3 * q + c)?);
                    }
                }
            }
            Ok((a, b, len, s))
        })
        .collect::<Result<_, &str>>()?;
    let ks = 500.0;

    // The user's time loop: implicit Euler with lumped mass m per vertex, gravity, the user's springs and
    // hinge's bending.
    let (dt, m, g) = (1.0 / 60.0, 1.0 / n as f64, -9.81);
    let mut v = vec![0.0; 3 * n];
    let (mut dx, mut rhs, mut diag) = (vec![0.0; 3 * n], vec![0.0; 3 * n], vec![0.0; 3 * n]);
    for step in 0..30 {
        let x_hat: Vec<f64> = x.iter().zip(&v).map(|(p, w)| p + dt * w).collect();
        let x_start = x.clone();
        x.clone_from(&x_hat);
        for (d, f) in fixed.iter().enumerate() {
            if *f {
                x[d] = x_start[d];
            }
        }
        let mut cg_total = 0;
        for _newton in 0..10 {
            // hinge evaluates on the user's flat buffer (viewed as vectors, no copy) …
            bending_energy = model.evaluate_to(
                x.as_vectors()?,
                Request::ALL,
                Method::Refactored,
                Parallelism::Rayon,
                &mut scratch,
                &mut grad,
                &mut lower,
            )?;
            // … and the Hessian goes into the user's CSR values.
            layout.scatter(&lower, &mut hessian.values)?;
            // The user's springs: ½ ks (l − L)², Hessian ks [d̂d̂ᵀ + max(0, 1 − L/l)(I − d̂d̂ᵀ)] (PSD).
            for (a, b, len, slots) in &springs {
                let d: Vec<f64> = (0..3).map(|k| x[3 * a + k] - x[3 * b + k]).collect();
                let l = d.iter().map(|v| v * v).sum::<f64>().sqrt();
                let u: Vec<f64> = d.iter().map(|v| v / l).collect();
                let (f, t) = (ks * (l - len), (1.0 - len / l).max(0.0));
                for k in 0..3 {
                    grad[3 * a + k] += f * u[k];
                    grad[3 * b + k] -= f * u[k];
                }
                for (blk, sign) in [1.0, -1.0, -1.0, 1.0].into_iter().enumerate() {
                    for r in 0..3 {
                        for c in 0..3 {
                            let eye = if r == c { 1.0 } else { 0.0 };
                            let e = ks * (u[r] * u[c] + t * (eye - u[r] * u[c]));
                            hessian.values[slots[9 * blk + 3 * r + c]] += sign * e;
                        }
                    }
                }
            }
            for (r, &k) in diag_slot.iter().enumerate() {
                hessian.values[k] += m / (dt * dt);
                diag[r] = hessian.values[k].max(1e-300);
            }
            for d in 0..3 * n {
                let gravity = if d % 3 == 2 { -m * g } else { 0.0 };
                rhs[d] = -(m / (dt * dt) * (x[d] - x_hat[d]) + grad[d] + gravity);
            }
            let res = rhs
                .iter()
                .zip(&fixed)
                .filter(|(_, f)| !**f)
                .map(|(r, _)| r * r)
                .sum::<f64>()
                .sqrt();
            if res < 1e-9 {
                break;
            }
            cg_total += my_cg(&hessian, &diag, &rhs, &fixed, &mut dx);
            for d in 0..3 * n {
                x[d] += dx[d];
            }
        }
        for d in 0..3 * n {
            v[d] = (x[d] - x_start[d]) / dt;
        }
        if step % 10 == 9 {
            let tip = (0..n).map(|i| x[3 * i + 2]).fold(f64::INFINITY, f64::min);
            println!(
                "step {:>2}: bending energy {:.4e}, lowest z {tip:.4}, CG iterations {cg_total}",
                step + 1,
                bending_energy
            );
        }
    }
    Ok(())
}
