//! Pinned (clamped) vertices: Dirichlet constraints a solver eliminates from its system.

use hinge_core::EvalError;

/// A set of pinned vertices, sorted and unique.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Pins {
    vertices: Vec<usize>,
    n_vertices: usize,
}

impl Pins {
    /// Pins `vertices` of a mesh with `n_vertices` vertices (duplicates are merged).
    ///
    /// # Errors
    /// [`EvalError::Pattern`] naming a vertex out of range.
    pub fn new(n_vertices: usize, mut vertices: Vec<usize>) -> Result<Self, EvalError> {
        if let Some(&v) = vertices.iter().find(|&&v| v >= n_vertices) {
            return Err(EvalError::Pattern {
                message: format!(
                    "pinned vertex {v} does not exist (the mesh has {n_vertices} vertices)"
                ),
            });
        }
        vertices.sort_unstable();
        vertices.dedup();
        Ok(Self {
            vertices,
            n_vertices,
        })
    }

    /// The pinned vertices, sorted.
    pub fn vertices(&self) -> &[usize] {
        &self.vertices
    }

    /// Whether vertex `v` is pinned.
    pub fn contains(&self, v: usize) -> bool {
        self.vertices.binary_search(&v).is_ok()
    }

    /// Per scalar degree of freedom (`3n`), whether it is free.
    pub fn free_dofs(&self) -> Vec<bool> {
        let mut free = vec![true; 3 * self.n_vertices];
        for &v in &self.vertices {
            free[3 * v..3 * v + 3].fill(false);
        }
        free
    }
}
