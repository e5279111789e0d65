//! Bring your own arrays: positions as `&[f64]` (x0, y0, z0, x1, …), `&[[f64; 3]]` or `&[Vector3<f64>]`,
//! triangles as `&[[u32; 3]]` or `&[[usize; 3]]`.
//!
//! Positions are *viewed* as `&[Vector3<f64>]` without copying ([`Positions::as_vectors`]: nalgebra's
//! `Vector3<f64>` is three contiguous `f64`s, and the cast is checked by bytemuck), so an evaluation on the
//! caller's buffer costs no copy. Triangles are converted once, when the rest mesh is built.
//!
//! ```
//! use hinge_core::layout::Positions;
//! use hinge_core::TriMesh;
//!
//! let flat = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
//! let tris: Vec<[u32; 3]> = vec![[0, 1, 2]];
//! let mesh = TriMesh::from_arrays(&flat[..], &tris[..]).unwrap();
//! // The same memory, seen as vectors:
//! let v = flat.as_vectors().unwrap();
//! assert_eq!(v[1].x, 1.0);
//! assert_eq!(v.as_ptr() as *const f64, flat.as_ptr());
//! assert!(flat[..4].as_vectors().is_err());
//! # let _ = mesh;
//! ```

use nalgebra::Vector3;

use crate::error::MeshError;

/// Vertex positions in a caller's layout, viewed as `&[Vector3<f64>]` without copying.
pub trait Positions {
    /// The positions as vectors (the same memory).
    ///
    /// # Errors
    /// [`MeshError::FlatLength`] when a flat array's length is not a multiple of 3.
    fn as_vectors(&self) -> Result<&[Vector3<f64>], MeshError>;
}

impl Positions for [f64] {
    fn as_vectors(&self) -> Result<&[Vector3<f64>], MeshError> {
        bytemuck::try_cast_slice(self).map_err(|_| MeshError::FlatLength { len: self.len() })
    }
}

impl Positions for [[f64; 3]] {
    fn as_vectors(&self) -> Result<&[Vector3<f64>], MeshError> {
        Ok(bytemuck::cast_slice(self))
    }
}

impl Positions for [Vector3<f64>] {
    fn as_vectors(&self) -> Result<&[Vector3<f64>], MeshError> {
        Ok(self)
    }
}

/// Triangles (vertex-index triples) in a caller's layout.
pub trait Triangles {
    /// The triangles as `usize` triples (a copy, made once per rest mesh).
    fn to_usize(&self) -> Vec<[usize; 3]>;
}

impl Triangles for [[u32; 3]] {
    fn to_usize(&self) -> Vec<[usize; 3]> {
        self.iter().map(|t| t.map(|v| v as usize)).collect()
    }
}

impl Triangles for [[usize; 3]] {
    fn to_usize(&self) -> Vec<[usize; 3]> {
        self.to_vec()
    }
}

/// A mutable view of a flat `3n` gradient buffer as vectors, for callers who keep forces as `[f64]`.
///
/// # Errors
/// [`MeshError::FlatLength`] when the length is not a multiple of 3.
pub fn as_vectors_mut(flat: &mut [f64]) -> Result<&mut [Vector3<f64>], MeshError> {
    let len = flat.len();
    bytemuck::try_cast_slice_mut(flat).map_err(|_| MeshError::FlatLength { len })
}
