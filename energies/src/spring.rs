//! Mass–spring energy on mesh edges (lecture P4–P5): `E = Σ_e ½ k (l_e − L_e)²` with `l_e = |x_i − x_j|` and
//! rest length `L_e`.
//!
//! Per edge with `d = x_i − x_j`, `d̂ = d / l`: `∇_i E = k (l − L) d̂ = −∇_j E`, and
//! `H_ii = H_jj = −H_ij = k [d̂ d̂ᵀ + (1 − L/l)(I − d̂ d̂ᵀ)]`. Under compression (`l < L`) the second term is
//! negative and can make the Hessian indefinite; [`MassSpring::drop_compressive_term`] clamps it to zero
//! (lecture P23), trading the exact Hessian for a positive semi-definite one; a
//! [`Request::definite`](hinge_core::bending::Request::definite) evaluation clamps it too.
//!
//! [`MassSpring::bending_springs`] puts the same springs across each hinge instead, between its two
//! opposite vertices x0 and x3: the "bending springs" the lecture shows to be a poor bending model (their
//! stiffness against a fold depends on the fold's direction relative to the mesh and vanishes to first
//! order at a flat hinge).

use std::sync::Arc;

use hinge_core::bending::{Parallelism, Request};
use hinge_core::energy::{Accumulator, Energy};
use hinge_core::nalgebra::{Matrix3, Vector3};
use hinge_core::pattern::SymmetricPattern;
use hinge_core::{ElementRef, EvalError, Topology, TriMesh};

use crate::util::{same_size, slot};

/// Springs on every edge of a mesh.
#[derive(Debug, Clone)]
pub struct MassSpring {
    name: &'static str,
    k: f64,
    edges: Vec<[usize; 2]>,
    rest_length: Vec<f64>,
    drop_compressive: bool,
    n_vertices: usize,
    slots: Vec<[usize; 3]>,
}

impl MassSpring {
    /// Springs of stiffness `k` on every edge of `rest`, rest lengths from `rest`.
    ///
    /// # Errors
    /// [`EvalError::Mesh`] for an invalid mesh; [`EvalError::Pattern`] for a non-finite or negative `k`.
    pub fn new(rest: &TriMesh, k: f64) -> Result<Self, EvalError> {
        if !(k >= 0.0 && k.is_finite()) {
            return Err(EvalError::Pattern {
                message: format!("spring stiffness k = {k} must be finite and non-negative"),
            });
        }
        let topo = Topology::new(rest.n_vertices(), rest.triangles())?;
        let x = rest.positions();
        let edges: Vec<[usize; 2]> = topo.edges().iter().map(|e| e.vertices).collect();
        let rest_length = edges.iter().map(|&[i, j]| (x[i] - x[j]).norm()).collect();
        Ok(Self {
            name: "mass-spring",
            k,
            edges,
            rest_length,
            drop_compressive: false,
            n_vertices: rest.n_vertices(),
            slots: Vec::new(),
        })
    }

    /// Bending springs: springs of stiffness `k` across every hinge, between its opposite vertices x0 and
    /// x3 (rest lengths from `rest`); named `bending-springs`.
    ///
    /// # Errors
    /// As [`MassSpring::new`].
    pub fn bending_springs(rest: &TriMesh, k: f64) -> Result<Self, EvalError> {
        let mut s = Self::new(rest, k)?;
        let topo = Topology::new(rest.n_vertices(), rest.triangles())?;
        let x = rest.positions();
        s.edges = topo
            .hinges()
            .iter()
            .map(|h| {
                let [a, b] = [h.vertices[0], h.vertices[3]];
                [a.min(b), a.max(b)]
            })
            .collect();
        s.rest_length = s.edges.iter().map(|&[i, j]| (x[i] - x[j]).norm()).collect();
        s.name = "bending-springs";
        Ok(s)
    }

    /// Drops the compressive term of the Hessian (lecture P23): positive semi-definite, no longer exact.
    pub fn drop_compressive_term(mut self, yes: bool) -> Self {
        self.drop_compressive = yes;
        self
    }

    /// The edges and their rest lengths.
    pub fn edges(&self) -> (&[[usize; 2]], &[f64]) {
        (&self.edges, &self.rest_length)
    }
}

impl Energy for MassSpring {
    // `k` (≥ 0): the energy is proportional to it.
    proportional_parameter!("k", k);

    fn name(&self) -> &str {
        self.name
    }

    fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    fn couplings(&self, out: &mut Vec<(usize, usize)>) {
        out.extend(self.edges.iter().map(|&[i, j]| (i, j)));
    }

    fn bind(&mut self, pattern: &Arc<SymmetricPattern>) -> Result<(), EvalError> {
        same_size(pattern, self.n_vertices)?;
        self.slots = self
            .edges
            .iter()
            .map(|&[i, j]| {
                Ok([
                    slot(pattern, i, i)?,
                    slot(pattern, j, j)?,
                    slot(pattern, i, j)?,
                ])
            })
            .collect::<Result<_, EvalError>>()?;
        Ok(())
    }

    fn add_to(
        &mut self,
        x: &[Vector3<f64>],
        request: Request,
        _: Parallelism,
        acc: &mut Accumulator,
    ) -> Result<f64, EvalError> {
        hinge_core::mesh::check_same_vertex_count(self.n_vertices, x.len())
            .map_err(EvalError::Mesh)?;
        let mut energy = 0.0;
        for (e, &[i, j]) in self.edges.iter().enumerate() {
            let d = x[i] - x[j];
            let l = d.norm();
            let big_l = self.rest_length[e];
            if !(l > 0.0) || !l.is_finite() {
                return Err(EvalError::AtElement {
                    energy: self.name().to_string(),
                    element: ElementRef::Edge([i, j]),
                    message: format!("length {l}: its direction is undefined"),
                });
            }
            let stretch = l - big_l;
            energy += 0.5 * self.k * stretch * stretch;
            let n = d / l;
            if request.gradient {
                let g = n * (self.k * stretch);
                acc.add_gradient(i, &g);
                acc.add_gradient(j, &-g);
            }
            if request.hessian && !self.slots.is_empty() {
                let nn = n * n.transpose();
                let mut t = 1.0 - big_l / l;
                if (self.drop_compressive || request.definite) && t < 0.0 {
                    t = 0.0;
                }
                let h = (nn + (Matrix3::identity() - nn) * t) * self.k;
                let s = self.slots[e];
                acc.add_block(s[0], i, i, &h);
                acc.add_block(s[1], j, j, &h);
                acc.add_block(s[2], i, j, &-h);
            }
        }
        Ok(if request.value { energy } else { 0.0 })
    }
}
