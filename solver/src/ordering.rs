//! Fill-reducing orderings for the sparse Cholesky factorization ([`crate::linear::FaerLlt`]).
//!
//! faer orders by approximate minimum degree (AMD). On the Hessians of closed shells and of large sheets a
//! nested dissection of the mesh graph leaves less fill: `shell-drop`'s icosphere (7 686 unknowns) 2.15 M
//! entries in `L` against AMD's 2.51 M, a 201×201 spring–bending cloth (121 203 unknowns) 41.4 M against
//! 50.3 M, each factorization faster in proportion; on the drape's 31×31 sheet AMD leaves less (286 k
//! against 384 k). [`FillOrdering::Auto`], the default, analyses both and keeps the one with the smaller
//! factor (see `hinge bench --only solve`).
//!
//! [`nested_dissection`] works on the graph of the pattern's 3×3 blocks (the vertices of this project's
//! Hessians, whose unknowns are `3v, 3v + 1, 3v + 2`; a dimension that is not a multiple of 3 is ordered
//! unknown by unknown). It splits a set of vertices by a level of a breadth-first search from a
//! pseudo-peripheral vertex (George & Liu's automatic nested dissection): among the levels that leave at
//! least 35 % of the set on each side the smallest, with the vertices that touch only one side moved to
//! it. Both sides are ordered first, recursively, the separator last; sets of at most [`ND_LEAF`] vertices
//! and every separator are ordered by faer's AMD on their own induced graph. It is deterministic and
//! sequential, so factorizations keep giving the same bits on any thread count.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::SymbolicSparseColMatRef;
use faer::sparse::linalg::amd;

use crate::linear::{LinearError, LowerCsc};

/// Sets of at most this many vertices are not dissected further (ordered by AMD).
pub const ND_LEAF: usize = 64;

/// Which fill-reducing ordering [`crate::linear::FaerLlt`] factors in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FillOrdering {
    /// Analyse with both and keep the ordering whose factor has fewer entries (AMD on a tie).
    #[default]
    Auto,
    /// faer's approximate minimum degree.
    Amd,
    /// [`nested_dissection`].
    NestedDissection,
}

impl FillOrdering {
    /// The scene-file name: `auto`, `amd`, `nested-dissection`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Amd => "amd",
            Self::NestedDissection => "nested-dissection",
        }
    }

    /// The ordering a scene-file name denotes ([`FillOrdering::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        [Self::Auto, Self::Amd, Self::NestedDissection]
            .into_iter()
            .find(|o| o.name() == name)
    }
}

/// The graph of a pattern's blocks in compressed rows (no self loops, neighbours sorted).
struct Graph {
    start: Vec<usize>,
    adj: Vec<usize>,
}

impl Graph {
    fn of(pattern: &LowerCsc, block: usize) -> Result<Self, LinearError> {
        pattern.check()?;
        let n = pattern.n / block;
        let mut edges = Vec::with_capacity(2 * pattern.row_idx.len() / (block * block) + 1);
        for j in 0..pattern.n {
            for &i in &pattern.row_idx[pattern.col_ptr[j]..pattern.col_ptr[j + 1]] {
                let (a, b) = (i / block, j / block);
                if a != b {
                    edges.push((a, b));
                    edges.push((b, a));
                }
            }
        }
        edges.sort_unstable();
        edges.dedup();
        let mut start = vec![0; n + 1];
        for &(a, _) in &edges {
            start[a + 1] += 1;
        }
        for v in 0..n {
            start[v + 1] += start[v];
        }
        Ok(Self {
            start,
            adj: edges.into_iter().map(|(_, b)| b).collect(),
        })
    }

    fn neighbours(&self, v: usize) -> &[usize] {
        &self.adj[self.start[v]..self.start[v + 1]]
    }
}

/// A nested-dissection elimination order of `pattern` (see the module documentation): entry `k` is the
/// unknown eliminated `k`-th, the convention of faer's `amd::order` and of
/// `SymmetricOrdering::Custom`'s forward permutation.
///
/// # Errors
/// [`LinearError::Usage`] for a malformed pattern, [`LinearError::Faer`] when faer's AMD fails (index
/// overflow).
pub fn nested_dissection(pattern: &LowerCsc) -> Result<Vec<usize>, LinearError> {
    let block = if pattern.n.is_multiple_of(3) { 3 } else { 1 };
    let g = Graph::of(pattern, block)?;
    let n = pattern.n / block;
    let mut order = Vec::with_capacity(n);
    let mut work = Work {
        mark: vec![0; n],
        level: vec![usize::MAX; n],
        local: vec![usize::MAX; n],
        queue: Vec::with_capacity(n),
        id: 0,
    };
    // Sets still to order; `true` marks a separator (ordered by AMD as it is).
    let mut stack: Vec<(Vec<usize>, bool)> = vec![((0..n).collect(), false)];
    while let Some((set, separator)) = stack.pop() {
        if separator || set.len() <= ND_LEAF {
            amd_of(&g, &set, &mut work.local, &mut order)?;
            continue;
        }
        match work.split(&g, &set) {
            Split::Components(components) => {
                // Popped in the order found.
                stack.extend(components.into_iter().rev().map(|c| (c, false)));
            }
            Split::Dissected { a, b, separator } => {
                if separator.is_empty() {
                    // Cannot happen (see `split`), but a set that does not shrink is ordered as it is
                    // rather than split again.
                    let set: Vec<usize> = a.into_iter().chain(b).collect();
                    amd_of(&g, &set, &mut work.local, &mut order)?;
                    continue;
                }
                // Popped in the order a, b, separator.
                stack.push((separator, true));
                stack.push((b, false));
                stack.push((a, false));
            }
        }
    }
    Ok(order
        .into_iter()
        .flat_map(|v| (0..block).map(move |c| block * v + c))
        .collect())
}

enum Split {
    /// The set is not connected: its connected components, all of them (found in one pass, so a set
    /// of many small pieces costs linear time, not quadratic).
    Components(Vec<Vec<usize>>),
    /// Two sides no edge joins, and the separator between them.
    Dissected {
        a: Vec<usize>,
        b: Vec<usize>,
        separator: Vec<usize>,
    },
}

struct Work {
    /// Which set a vertex belongs to while that set is being split (`id`).
    mark: Vec<u32>,
    level: Vec<usize>,
    local: Vec<usize>,
    queue: Vec<usize>,
    id: u32,
}

impl Work {
    /// Breadth-first search within the marked set from `start`: fills `queue` in visiting order and
    /// `level`; returns the depth.
    fn bfs(&mut self, g: &Graph, start: usize) -> usize {
        for &v in &self.queue {
            self.level[v] = usize::MAX;
        }
        self.queue.clear();
        self.queue.push(start);
        self.level[start] = 0;
        let mut head = 0;
        while head < self.queue.len() {
            let v = self.queue[head];
            head += 1;
            for &w in g.neighbours(v) {
                if self.mark[w] == self.id && self.level[w] == usize::MAX {
                    self.level[w] = self.level[v] + 1;
                    self.queue.push(w);
                }
            }
        }
        self.queue.last().map_or(0, |&v| self.level[v])
    }

    fn split(&mut self, g: &Graph, set: &[usize]) -> Split {
        self.id += 1;
        for &v in set {
            self.mark[v] = self.id;
        }
        let mut start = set[0];
        let mut depth = self.bfs(g, start);
        if self.queue.len() < set.len() {
            self.reset();
            return Split::Components(self.components(g, set));
        }
        // Pseudo-peripheral start: restart from a vertex of the last level with the fewest neighbours
        // while the depth grows (at most 8 rounds).
        for _ in 0..8 {
            let candidate = self
                .queue
                .iter()
                .copied()
                .filter(|&v| self.level[v] == depth)
                .min_by_key(|&v| (g.neighbours(v).len(), v));
            let Some(candidate) = candidate else { break };
            let d = self.bfs(g, candidate);
            if d <= depth {
                break;
            }
            start = candidate;
            depth = d;
        }
        let depth = self.bfs(g, start);
        let mut count = vec![0usize; depth + 1];
        for &v in &self.queue {
            count[self.level[v]] += 1;
        }
        // The smallest level with at least 35 % of the set on each side; else the median level.
        let m = set.len();
        let (mut below, mut median) = (0, 0);
        let mut best: Option<(usize, usize)> = None;
        for (l, &c) in count.iter().enumerate() {
            let above = m - below - c;
            if 2 * below <= m {
                median = l;
            }
            if 20 * below >= 7 * m && 20 * above >= 7 * m && best.is_none_or(|(_, bc)| c < bc) {
                best = Some((l, c));
            }
            below += c;
        }
        // Never the deepest level: a cut there has nothing beyond it, so it would give back the whole set
        // as one side and the dissection would never end (a fan around one vertex puts most of a set on
        // the deepest level, and the median falls there). Above it, every vertex beyond the cut has a
        // breadth-first parent on it, so the separator is not empty and both sides are smaller than the
        // set. `depth ≥ 1` here: the set is connected and has more than `ND_LEAF` vertices.
        let cut = best.map_or(median, |(l, _)| l).min(depth.saturating_sub(1));
        let (mut a, mut b, mut separator) = (Vec::new(), Vec::new(), Vec::new());
        for &v in &self.queue {
            match self.level[v].cmp(&cut) {
                std::cmp::Ordering::Less => a.push(v),
                std::cmp::Ordering::Greater => b.push(v),
                std::cmp::Ordering::Equal => {
                    // Every vertex of the set is reached (it is connected), so a marked neighbour has a
                    // level. A separator vertex with no neighbour beyond the cut separates nothing: it
                    // joins a.
                    if g.neighbours(v)
                        .iter()
                        .any(|&w| self.mark[w] == self.id && self.level[w] > cut)
                    {
                        separator.push(v);
                    } else {
                        a.push(v);
                    }
                }
            }
        }
        self.reset();
        Split::Dissected { a, b, separator }
    }

    /// The connected components of the marked set `set`, each in breadth-first order, in the order of
    /// their first vertex in `set`.
    fn components(&mut self, g: &Graph, set: &[usize]) -> Vec<Vec<usize>> {
        let mut components = Vec::new();
        for &s in set {
            if self.level[s] != usize::MAX {
                continue;
            }
            let first = self.queue.len();
            self.queue.push(s);
            self.level[s] = 0;
            let mut head = first;
            while head < self.queue.len() {
                let v = self.queue[head];
                head += 1;
                for &w in g.neighbours(v) {
                    if self.mark[w] == self.id && self.level[w] == usize::MAX {
                        self.level[w] = 0;
                        self.queue.push(w);
                    }
                }
            }
            components.push(self.queue[first..].to_vec());
        }
        self.reset();
        components
    }

    fn reset(&mut self) {
        for &v in &self.queue {
            self.level[v] = usize::MAX;
        }
        self.queue.clear();
    }
}

/// Appends `set` in the order of faer's AMD on the graph it induces.
fn amd_of(
    g: &Graph,
    set: &[usize],
    local: &mut [usize],
    order: &mut Vec<usize>,
) -> Result<(), LinearError> {
    if set.len() <= 2 {
        order.extend_from_slice(set);
        return Ok(());
    }
    for (k, &v) in set.iter().enumerate() {
        local[v] = k;
    }
    let mut col_ptr = Vec::with_capacity(set.len() + 1);
    col_ptr.push(0);
    let mut row_idx = Vec::new();
    for &v in set {
        let first = row_idx.len();
        row_idx.push(local[v]);
        row_idx.extend(
            g.neighbours(v)
                .iter()
                .filter(|&&w| local[w] != usize::MAX)
                .map(|&w| local[w]),
        );
        row_idx[first..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    for &v in set {
        local[v] = usize::MAX;
    }
    let m = set.len();
    let pattern = SymbolicSparseColMatRef::new_checked(m, m, &col_ptr, None, &row_idx);
    let (mut perm, mut inverse) = (vec![0usize; m], vec![0usize; m]);
    let mut buffer = MemBuffer::new(amd::order_scratch::<usize>(m, row_idx.len()));
    amd::order(
        &mut perm,
        &mut inverse,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut buffer),
    )
    .map_err(|e| LinearError::Faer(format!("{e:?}")))?;
    order.extend(perm.iter().map(|&k| set[k]));
    Ok(())
}
