//! Set-up: the storage order of the elements and hinge states, every local block's value slot, and the
//! partition of the work. All of it follows the pattern's storage order (a locality order of the vertices),
//! never the caller's numbering, so that pass 2 walks the value array and the positions front to back.

use crate::pattern::SymmetricPattern;
use crate::topology::Topology;

use super::scatter::{NO_SLOT, NONE, Slot};

/// Vertices per partition on large meshes. An element straddling two partitions is computed by both, so
/// partitions must be many rows of a mesh deep (8192 vertices are 20 rows of a 401² grid: ~5% repeated work).
const PARTITION_VERTICES: usize = 8192;
/// Small meshes still get this many partitions (of at least `MIN_PARTITION_VERTICES` each) so a few threads
/// have work to share.
const MIN_PARTITIONS: usize = 4;
const MIN_PARTITION_VERTICES: usize = 512;

/// A contiguous range of storage positions and the elements touching it.
#[derive(Debug, Clone)]
pub(super) struct Partition {
    /// Storage positions owned.
    pub vertices: std::ops::Range<usize>,
    /// Value offsets owned (the block columns of `vertices`).
    pub values: std::ops::Range<usize>,
    /// Indices into `Layout::tri_elements`, increasing.
    pub tris: Vec<u32>,
    /// State slots of the hinges touching the range, increasing.
    pub hinges: Vec<u32>,
}

/// Everything that depends on the pattern's storage order.
#[derive(Debug, Clone, Default)]
pub(super) struct Layout {
    /// Triangles with at least one interior edge (the refactored elements), sorted by their first vertex in
    /// storage order.
    pub tri_elements: Vec<u32>,
    /// Per element: its corners' storage positions, in the mesh's corner order.
    pub tri_vertices: Vec<[u32; 3]>,
    /// Per element: the topology's orientation bits (bit k: edge k runs low → high caller index).
    pub tri_bits: Vec<u8>,
    /// Per element: 6 own block slots (00, 11, 22, 01, 12, 20 by corner) and 4 x3 slots for each corner whose
    /// edge is the element's assigned hinge (x3x3, x3x0, x3x1, x3x2).
    pub tri_slots: Vec<[Slot; 18]>,
    /// Per element: the state slot of the hinge on each of its edges (NONE on the boundary).
    pub tri_states: Vec<[u32; 3]>,
    /// Per element: its corners whose edge carries an assigned hinge (the triangle is that hinge's T), in
    /// increasing state slot, then `3` for none: contributions are added in an order that does not depend on
    /// which corner the face lists first.
    pub tri_assigned: Vec<[u8; 3]>,
    /// Per element: the value offset just past the block column of the highest storage position it writes
    /// a block into (its corners and its hinges' x3). Pass 2 zeroes a partition's values only up to here
    /// before the element adds into them: a frontier that moves through the value array with the
    /// elements, so the zeroed entries are still in cache when they are added to.
    pub tri_zero_end: Vec<u32>,
    /// Hinge states in the order the refactored pass consumes them (each hinge right where its upper
    /// triangle T is visited): slot → hinge.
    pub state_order: Vec<u32>,
    /// Stencil x0..x3 per slot, as storage positions.
    pub state_vertices: Vec<[u32; 4]>,
    /// Per slot: 10 block slots (00, 11, 22, 33, 10, 20, 30, 21, 31, 32).
    pub hinge_slots: Vec<[Slot; 10]>,
    /// The partitions of pass 2.
    pub partitions: Vec<Partition>,
    /// Per storage block column: the length of its first scalar column (for [`super::scatter::block_offsets`]).
    pub col_len: Vec<u32>,
}

/// The vertex pairs of a hinge energy on `topology` (the caller's numbering).
pub(super) fn couplings(topology: &Topology, d2_is_zero: bool) -> Vec<(usize, usize)> {
    let tris = topology.triangles();
    let mut pairs = Vec::with_capacity(3 * tris.len() + topology.hinges().len());
    for (t, v) in tris.iter().enumerate() {
        if topology.triangle_edges()[t]
            .iter()
            .any(|&e| topology.hinge_of_edge(e).is_some())
        {
            pairs.extend([(v[0], v[1]), (v[1], v[2]), (v[2], v[0])]);
        }
    }
    if !d2_is_zero {
        pairs.extend(
            topology
                .hinges()
                .iter()
                .map(|h| (h.vertices[0], h.vertices[3])),
        );
    }
    pairs
}

impl Layout {
    /// The layout of `topology`'s hinge energy on `pattern` (which holds all of [`couplings`]).
    pub fn new(topology: &Topology, pattern: &SymmetricPattern) -> Self {
        let rank = |v: usize| pattern.storage_of(v) as u32;
        let tris = topology.triangles();
        let bits = topology.orientation_bits();
        let edge_hinge = |e: usize| topology.hinge_of_edge(e).map_or(NONE, |h| h as u32);
        let mut tri_elements: Vec<u32> = (0..tris.len())
            .filter(|&t| {
                topology.triangle_edges()[t]
                    .iter()
                    .any(|&e| edge_hinge(e) != NONE)
            })
            .map(|t| t as u32)
            .collect();
        // A rotation-invariant key: the first corner in storage order (then the triangle index).
        tri_elements.sort_by_key(|&t| {
            let v = tris[t as usize];
            (rank(v[0]).min(rank(v[1])).min(rank(v[2])), t)
        });
        let mut state_order = Vec::with_capacity(topology.hinges().len());
        for &t in &tri_elements {
            // The triangle's assigned hinges by hinge index, not by corner: the same order whichever corner
            // the face lists first.
            let mut own: Vec<u32> = (0..3)
                .map(|k| edge_hinge(topology.triangle_edges()[t as usize][k]))
                .enumerate()
                .filter(|&(k, h)| h != NONE && bits[t as usize] >> k & 1 == 1)
                .map(|(_, h)| h)
                .collect();
            own.sort_unstable();
            state_order.extend(own);
        }
        let mut state_of = vec![NONE; topology.hinges().len()];
        for (slot, &h) in state_order.iter().enumerate() {
            state_of[h as usize] = slot as u32;
        }
        let tri_states: Vec<[u32; 3]> = tri_elements
            .iter()
            .map(|&t| {
                topology.triangle_edges()[t as usize].map(|e| {
                    let h = edge_hinge(e);
                    if h == NONE {
                        NONE
                    } else {
                        state_of[h as usize]
                    }
                })
            })
            .collect();
        let tri_assigned = tri_elements
            .iter()
            .zip(&tri_states)
            .map(|(&t, st)| {
                let mut a = [3u8; 3];
                let mut ks: Vec<usize> = (0..3)
                    .filter(|&k| st[k] != NONE && bits[t as usize] >> k & 1 == 1)
                    .collect();
                ks.sort_unstable_by_key(|&k| st[k]);
                for (i, k) in ks.into_iter().enumerate() {
                    a[i] = k as u8;
                }
                a
            })
            .collect();
        let state_vertices: Vec<[u32; 4]> = state_order
            .iter()
            .map(|&h| topology.hinges()[h as usize].vertices.map(rank))
            .collect();
        let tri_vertices: Vec<[u32; 3]> = tri_elements
            .iter()
            .map(|&t| tris[t as usize].map(rank))
            .collect();
        let tri_bits = tri_elements.iter().map(|&t| bits[t as usize]).collect();
        // All the hinges' x3, a superset of the assigned ones the element writes: zeroing ahead is safe.
        let tri_zero_end = tri_vertices
            .iter()
            .zip(&tri_states)
            .map(|(v, states)| {
                let mut top = v[0].max(v[1]).max(v[2]);
                for &st in states {
                    if st != NONE {
                        top = top.max(state_vertices[st as usize][3]);
                    }
                }
                pattern.block_col_value_start(top as usize + 1) as u32
            })
            .collect();
        let slot = |a: u32, b: u32| {
            pattern
                .find_storage(a as usize, b as usize)
                .map_or(NO_SLOT, |s| pattern.blocks()[s].offset[0])
        };
        let tri_slots = tri_elements
            .iter()
            .zip(&tri_states)
            .zip(&tri_vertices)
            .map(|((&t, states), v)| {
                let mut s = [NO_SLOT; 18];
                s[..6].copy_from_slice(&[
                    slot(v[0], v[0]),
                    slot(v[1], v[1]),
                    slot(v[2], v[2]),
                    slot(v[0], v[1]),
                    slot(v[1], v[2]),
                    slot(v[2], v[0]),
                ]);
                for k in 0..3 {
                    if states[k] != NONE && bits[t as usize] >> k & 1 == 1 {
                        let hv = state_vertices[states[k] as usize];
                        s[6 + 4 * k..10 + 4 * k].copy_from_slice(&[
                            slot(hv[3], hv[3]),
                            slot(hv[3], hv[0]),
                            slot(hv[3], hv[1]),
                            slot(hv[3], hv[2]),
                        ]);
                    }
                }
                s
            })
            .collect();
        let hinge_slots = state_vertices
            .iter()
            .map(|v| {
                [
                    slot(v[0], v[0]),
                    slot(v[1], v[1]),
                    slot(v[2], v[2]),
                    slot(v[3], v[3]),
                    slot(v[1], v[0]),
                    slot(v[2], v[0]),
                    slot(v[3], v[0]),
                    slot(v[2], v[1]),
                    slot(v[3], v[1]),
                    slot(v[3], v[2]),
                ]
            })
            .collect();
        let mut layout = Self {
            tri_elements,
            tri_vertices,
            tri_bits,
            tri_slots,
            tri_states,
            tri_assigned,
            tri_zero_end,
            state_order,
            state_vertices,
            hinge_slots,
            partitions: Vec::new(),
            col_len: (0..pattern.n_vertices())
                .map(|j| (pattern.col_ptr()[3 * j + 1] - pattern.col_ptr()[3 * j]) as u32)
                .collect(),
        };
        layout.partitions = layout.build_partitions(pattern);
        layout
    }

    /// Per-hinge values (hinge order) rearranged into state-slot order.
    pub fn in_slot_order<T: Copy>(&self, by_hinge: &[T]) -> Vec<T> {
        self.state_order
            .iter()
            .map(|&h| by_hinge[h as usize])
            .collect()
    }

    fn build_partitions(&self, pattern: &SymmetricPattern) -> Vec<Partition> {
        let n = pattern.n_vertices();
        // Fixed by the mesh alone, never by the thread count (results do not depend on it anyway).
        let count = n
            .div_ceil(PARTITION_VERTICES)
            .max(MIN_PARTITIONS.min(n.div_ceil(MIN_PARTITION_VERTICES)))
            .max(1);
        let mut parts: Vec<Partition> = (0..count)
            .map(|p| {
                let vs = p * n / count..(p + 1) * n / count;
                Partition {
                    values: pattern.block_col_value_start(vs.start)
                        ..pattern.block_col_value_start(vs.end),
                    vertices: vs,
                    tris: Vec::new(),
                    hinges: Vec::new(),
                }
            })
            .collect();
        // The partition owning each storage position.
        let mut owner_of = vec![0usize; n];
        for (p, part) in parts.iter().enumerate() {
            owner_of[part.vertices.clone()].fill(p);
        }
        let owner = |v: u32| owner_of[v as usize];
        let mut owners: Vec<usize> = Vec::with_capacity(9);
        for (e, v) in self.tri_vertices.iter().enumerate() {
            owners.clear();
            owners.extend(v.iter().map(|&x| owner(x)));
            for &st in &self.tri_states[e] {
                if st != NONE {
                    let hv = self.state_vertices[st as usize];
                    owners.push(owner(hv[3]));
                    owners.push(owner(hv[0]));
                }
            }
            owners.sort_unstable();
            owners.dedup();
            for &p in &owners {
                parts[p].tris.push(e as u32);
            }
        }
        for (slot, hv) in self.state_vertices.iter().enumerate() {
            owners.clear();
            owners.extend(hv.iter().map(|&x| owner(x)));
            owners.sort_unstable();
            owners.dedup();
            for &p in &owners {
                parts[p].hinges.push(slot as u32);
            }
        }
        parts
    }
}
