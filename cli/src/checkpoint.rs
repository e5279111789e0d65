//! Checkpoints of a time-stepped run: the state `hinge run` needs to continue it (`--resume FILE`).
//!
//! A run with an output directory writes `checkpoint.txt` there when it ends: after its last frame, when
//! Ctrl-C stops it, and when a frame fails (then the checkpoint holds the last good frame, the state the
//! failed frame started from). `hinge run SCENE --resume checkpoint.txt` continues from it: with the scene
//! unchanged, the frames it writes are bitwise those the run would have written had it not stopped
//! (positions, velocities, the time, the Newton solver's shift memory and the plastic state are all in the
//! file, the floating-point numbers in a form that reads back exactly). A changed scene is taken as
//! given — a smaller `dt`, a stiffer contact or more frames after a failure —, as long as the mesh has the
//! checkpoint's vertices (and hinges, for plasticity).
//!
//! The file is text, one item per line:
//!
//! ```text
//! hinge checkpoint 2
//! scene drape
//! frame 46
//! time 7.666666666666667e-1
//! dt 1.6666666666666666e-2
//! shift_memory 3.2e-1
//! warned_obstacles 0      (obstacles that no longer warn, by index; possibly none)
//! vertices 961
//! plastic_hinges 0
//! x y z vx vy vz          (one line per vertex)
//! theta_bar alpha         (one line per hinge, only with plasticity)
//! ```
//!
//! Version 1 (before 2026-12-08) had no `warned_obstacles` line; it is read as none.

use std::path::Path;

use hinge_core::nalgebra::Vector3;

/// The first line of every checkpoint (the format's version).
const HEADER: &str = "hinge checkpoint 2";

/// The first line of a version-1 checkpoint (no `warned_obstacles` line), still read.
const HEADER_1: &str = "hinge checkpoint 1";

/// The state of a time-stepped run after some frame (see the module documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// The scene's name (for the reader; not checked on resume).
    pub scene: String,
    /// The frame whose end this is (0: the start).
    pub frame: usize,
    /// The time of that frame's end (s).
    pub time: f64,
    /// The time step the frames were taken with (s).
    pub dt: f64,
    /// The Newton solver's shift memory ([`hinge_solver::newton::Newton::shift_memory`]; 0 for the
    /// explicit integrator).
    pub shift_memory: f64,
    /// Positions (m).
    pub positions: Vec<Vector3<f64>>,
    /// Velocities (m/s).
    pub velocities: Vec<Vector3<f64>>,
    /// With bending plasticity: the rest angles θ̄ and accumulated plastic angles α (rad, hinge order).
    pub plastic: Option<(Vec<f64>, Vec<f64>)>,
    /// The obstacles (indices in the scene's list) that no longer warn of vertices inside them: their
    /// warning was given before the checkpoint (or they never warn, as barriers): a resumed run does not
    /// give it again.
    pub warned_obstacles: Vec<usize>,
}

impl Checkpoint {
    /// The file's text (numbers in Rust's shortest round-trip form: they read back exactly).
    pub fn to_text(&self) -> String {
        let mut s = String::with_capacity(160 + 150 * self.positions.len());
        s.push_str(HEADER);
        s.push('\n');
        s.push_str(&format!(
            "scene {}\n",
            self.scene.replace(['\n', '\r'], " ")
        ));
        s.push_str(&format!("frame {}\n", self.frame));
        s.push_str(&format!("time {:e}\n", self.time));
        s.push_str(&format!("dt {:e}\n", self.dt));
        s.push_str(&format!("shift_memory {:e}\n", self.shift_memory));
        s.push_str("warned_obstacles");
        for i in &self.warned_obstacles {
            s.push_str(&format!(" {i}"));
        }
        s.push('\n');
        s.push_str(&format!("vertices {}\n", self.positions.len()));
        let plastic = self.plastic.as_ref().map_or(0, |(t, _)| t.len());
        s.push_str(&format!("plastic_hinges {plastic}\n"));
        for (x, v) in self.positions.iter().zip(&self.velocities) {
            s.push_str(&format!(
                "{:e} {:e} {:e} {:e} {:e} {:e}\n",
                x.x, x.y, x.z, v.x, v.y, v.z
            ));
        }
        if let Some((theta_bar, alpha)) = &self.plastic {
            for (t, a) in theta_bar.iter().zip(alpha) {
                s.push_str(&format!("{t:e} {a:e}\n"));
            }
        }
        s
    }

    /// An upper bound on the size in bytes of [`Checkpoint::to_text`] for `n_vertices` vertices,
    /// `plastic_hinges` hinges with a plastic state, `obstacles` obstacles and a scene named `scene`: every
    /// number takes at most 24 characters (a sign, 17 significant digits, a point and a three-digit
    /// exponent), so a vertex line 150 bytes and a hinge line 50, an obstacle index 21, and the header lines
    /// at most 256 beside the scene's name.
    pub fn max_bytes(
        n_vertices: usize,
        plastic_hinges: usize,
        obstacles: usize,
        scene: &str,
    ) -> u64 {
        256 + scene.len() as u64
            + 150 * n_vertices as u64
            + 50 * plastic_hinges as u64
            + 21 * obstacles as u64
    }

    /// Writes the file (to a temporary file beside it, then renamed: a run stopped while writing leaves
    /// the previous checkpoint or none, never half of one).
    ///
    /// # Errors
    /// A one-line message naming the file.
    pub fn write(&self, path: &Path) -> Result<(), String> {
        let tmp = path.with_extension("txt.partial");
        std::fs::write(&tmp, self.to_text()).map_err(|e| format!("{}: {e}", tmp.display()))?;
        std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Reads a checkpoint file.
    ///
    /// # Errors
    /// A one-line message naming the file and the line at fault.
    pub fn read(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Parses a checkpoint's text.
    ///
    /// # Errors
    /// A one-line message naming the line at fault (counted from 1): a missing or unknown header, a
    /// missing item, a number that does not parse or is not finite, a negative shift memory or
    /// accumulated plastic angle, a non-positive `dt`, missing or extra lines.
    pub fn parse(text: &str) -> Result<Self, String> {
        // Capacities from the lines there are, not from the counts the file claims (a damaged count).
        let available = text.lines().count();
        let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim()));
        let mut next = |what: &str| -> Result<(usize, &str), String> {
            lines.next().ok_or_else(|| format!("ends before {what}"))
        };
        let (n, header) = next("its header")?;
        if header != HEADER && header != HEADER_1 {
            return Err(format!(
                "line {n}: not a hinge checkpoint (expected `{HEADER}`, found `{}`)",
                shorten(header)
            ));
        }
        let version_1 = header == HEADER_1;
        let mut item = |key: &str| -> Result<(usize, String), String> {
            let (n, line) = next(&format!("`{key}`"))?;
            match line.split_once(' ') {
                Some((k, value)) if k == key => Ok((n, value.trim().to_string())),
                _ if line == key => Ok((n, String::new())),
                _ => Err(format!(
                    "line {n}: expected `{key} …`, found `{}`",
                    shorten(line)
                )),
            }
        };
        let (_, scene) = item("scene")?;
        let count = |(n, value): (usize, String), key: &str| -> Result<usize, String> {
            value
                .parse::<usize>()
                .map_err(|_| format!("line {n}: {key} `{}` is not a count", shorten(&value)))
        };
        let number = |(n, value): (usize, String), key: &str| -> Result<f64, String> {
            parse_number(&value).map_err(|m| format!("line {n}: {key} {m}"))
        };
        let frame = count(item("frame")?, "frame")?;
        let time = number(item("time")?, "time")?;
        let (n_dt, dt_text) = item("dt")?;
        let dt = number((n_dt, dt_text), "dt")?;
        if dt <= 0.0 {
            return Err(format!("line {n_dt}: dt must be positive, got {dt:e}"));
        }
        let (n_shift, shift_text) = item("shift_memory")?;
        let shift_memory = number((n_shift, shift_text), "shift_memory")?;
        if shift_memory < 0.0 {
            return Err(format!(
                "line {n_shift}: shift_memory must be non-negative, got {shift_memory:e}"
            ));
        }
        let mut warned_obstacles = Vec::new();
        if !version_1 {
            let (n, value) = item("warned_obstacles")?;
            for w in value.split_whitespace() {
                warned_obstacles.push(w.parse::<usize>().map_err(|_| {
                    format!(
                        "line {n}: warned_obstacles `{}` is not an index",
                        shorten(w)
                    )
                })?);
            }
        }
        let vertices = count(item("vertices")?, "vertices")?;
        let hinges = count(item("plastic_hinges")?, "plastic_hinges")?;
        let mut positions = Vec::with_capacity(vertices.min(available));
        let mut velocities = Vec::with_capacity(vertices.min(available));
        for vertex in 0..vertices {
            let (n, line) = next(&format!("vertex {vertex} (of {vertices})"))?;
            let values =
                numbers::<6>(line).map_err(|m| format!("line {n} (vertex {vertex}): {m}"))?;
            positions.push(Vector3::new(values[0], values[1], values[2]));
            velocities.push(Vector3::new(values[3], values[4], values[5]));
        }
        let plastic = if hinges == 0 {
            None
        } else {
            let mut theta_bar = Vec::with_capacity(hinges.min(available));
            let mut alpha = Vec::with_capacity(hinges.min(available));
            for hinge in 0..hinges {
                let (n, line) = next(&format!("hinge {hinge} (of {hinges})"))?;
                let [t, a] =
                    numbers::<2>(line).map_err(|m| format!("line {n} (hinge {hinge}): {m}"))?;
                if a < 0.0 {
                    return Err(format!(
                        "line {n} (hinge {hinge}): the accumulated plastic angle must be non-negative, \
                         got {a:e}"
                    ));
                }
                theta_bar.push(t);
                alpha.push(a);
            }
            Some((theta_bar, alpha))
        };
        if let Some((n, line)) = lines.find(|(_, l)| !l.is_empty()) {
            return Err(format!(
                "line {n}: more lines than its {vertices} vertices and {hinges} plastic hinges (`{}`)",
                shorten(line)
            ));
        }
        Ok(Checkpoint {
            scene,
            frame,
            time,
            dt,
            shift_memory,
            positions,
            velocities,
            plastic,
            warned_obstacles,
        })
    }
}

/// A finite number, or what is wrong with it.
fn parse_number(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        Ok(x) => Err(format!("is not finite ({x})")),
        Err(_) => Err(format!("`{}` is not a number", shorten(s))),
    }
}

/// Exactly `N` finite numbers separated by white space.
fn numbers<const N: usize>(line: &str) -> Result<[f64; N], String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    if words.len() != N {
        return Err(format!("expected {N} numbers, found {}", words.len()));
    }
    let mut out = [0.0; N];
    for (k, (o, w)) in out.iter_mut().zip(&words).enumerate() {
        *o = parse_number(w).map_err(|m| format!("number {} {m}", k + 1))?;
    }
    Ok(out)
}

/// At most 40 characters of `s`, for messages.
fn shorten(s: &str) -> String {
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`Checkpoint::max_bytes`] bounds the text of the longest numbers there are (negative, 17
    /// significant digits, three-digit negative exponents) and of the largest counts, and is within a few
    /// bytes per line of it.
    #[test]
    fn the_size_bound_holds_for_the_longest_numbers() {
        let long = -2.2250738585072014e-308_f64;
        let longest = |n: usize| vec![Vector3::new(long, long, long); n];
        for (n, h, o) in [(0, 0, 0), (1, 0, 1), (3, 5, 2), (1000, 2900, 40)] {
            let c = Checkpoint {
                scene: "a scene".into(),
                frame: usize::MAX,
                time: long,
                dt: long,
                shift_memory: long,
                positions: longest(n),
                velocities: longest(n),
                plastic: (h > 0).then(|| (vec![long; h], vec![long; h])),
                warned_obstacles: vec![usize::MAX; o],
            };
            assert_eq!(format!("{long:e}").len(), 24);
            let len = c.to_text().len() as u64;
            let bound = Checkpoint::max_bytes(n, h, o, &c.scene);
            assert!(len <= bound, "{n} vertices, {h} hinges: {len} > {bound}");
            assert!(
                bound - len <= 256,
                "{n} vertices, {h} hinges: {len} ≪ {bound}"
            );
        }
    }

    fn sample(plastic: bool) -> Checkpoint {
        // Numbers whose shortest forms are long, tiny, huge, negative zero and subnormal.
        Checkpoint {
            scene: "drape".into(),
            frame: 46,
            time: 46.0 * (1.0 / 60.0),
            dt: 1.0 / 60.0,
            shift_memory: 0.1 + 0.2,
            positions: vec![
                Vector3::new(0.1, -2.0 / 3.0, 1e-300),
                Vector3::new(-0.0, 5e-324, 1.7976931348623157e308),
            ],
            velocities: vec![
                Vector3::new(std::f64::consts::PI, -1e-17, 0.0),
                Vector3::new(2.0f64.sqrt(), -7.0, 1.0 / 3.0),
            ],
            plastic: plastic.then(|| (vec![0.25, -3.0], vec![0.0, 1.0 / 7.0])),
            warned_obstacles: if plastic { vec![0, 3] } else { Vec::new() },
        }
    }

    /// A version-1 file (no `warned_obstacles` line) reads as a checkpoint with none.
    #[test]
    fn version_1_checkpoints_are_read() {
        let c = sample(true);
        let text = c.to_text();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], HEADER);
        assert_eq!(lines[6], "warned_obstacles 0 3");
        let old: String = std::iter::once(HEADER_1)
            .chain(lines[1..6].iter().copied())
            .chain(lines[7..].iter().copied())
            .map(|l| format!("{l}\n"))
            .collect();
        let back = Checkpoint::parse(&old).unwrap();
        assert_eq!(
            back,
            Checkpoint {
                warned_obstacles: Vec::new(),
                ..c
            }
        );
    }

    #[test]
    fn checkpoints_read_back_bitwise() {
        for plastic in [false, true] {
            let c = sample(plastic);
            let back = Checkpoint::parse(&c.to_text()).unwrap();
            assert_eq!(back, c);
            let bits = |v: &[Vector3<f64>]| -> Vec<u64> {
                v.iter()
                    .flat_map(|p| p.iter().map(|x| x.to_bits()))
                    .collect()
            };
            assert_eq!(bits(&back.positions), bits(&c.positions));
            assert_eq!(bits(&back.velocities), bits(&c.velocities));
            assert_eq!(back.time.to_bits(), c.time.to_bits());
            assert_eq!(back.shift_memory.to_bits(), c.shift_memory.to_bits());
        }
    }

    #[test]
    fn bad_checkpoints_name_their_line() {
        let good = sample(true).to_text();
        let replace_line = |k: usize, with: &str| -> String {
            good.lines()
                .enumerate()
                .map(|(i, l)| if i + 1 == k { with } else { l })
                .collect::<Vec<_>>()
                .join("\n")
        };
        let cases: Vec<(String, &str)> = vec![
            (String::new(), "ends before its header"),
            ("hinge frames 1\n".into(), "line 1: not a hinge checkpoint"),
            (
                replace_line(3, "frame -1"),
                "line 3: frame `-1` is not a count",
            ),
            (
                replace_line(4, "time nan"),
                "line 4: time is not finite (NaN)",
            ),
            (replace_line(5, "dt 0"), "line 5: dt must be positive"),
            (
                replace_line(6, "shift_memory -1"),
                "line 6: shift_memory must be non-negative",
            ),
            (
                replace_line(6, "shift 1"),
                "line 6: expected `shift_memory …`, found `shift 1`",
            ),
            (
                replace_line(7, "warned_obstacles 0 -1"),
                "line 7: warned_obstacles `-1` is not an index",
            ),
            (
                replace_line(7, "vertices 2"),
                "line 7: expected `warned_obstacles …`, found `vertices 2`",
            ),
            (
                replace_line(10, "1 2 3 4 5"),
                "line 10 (vertex 0): expected 6 numbers, found 5",
            ),
            (
                replace_line(11, "1 2 3 4 inf 6"),
                "line 11 (vertex 1): number 5 is not finite (inf)",
            ),
            (
                replace_line(12, "0.1 x"),
                "line 12 (hinge 0): number 2 `x` is not a number",
            ),
            (
                replace_line(13, "0.1 -0.5"),
                "line 13 (hinge 1): the accumulated plastic angle",
            ),
            (
                good.lines().take(12).collect::<Vec<_>>().join("\n"),
                "ends before hinge 1 (of 2)",
            ),
            (
                format!("{good}1 2\n"),
                "line 14: more lines than its 2 vertices and 2 plastic",
            ),
            (
                replace_line(8, "vertices 18446744073709551615"),
                "line 12 (vertex 2): expected 6 numbers, found 2",
            ),
        ];
        for (text, expected) in cases {
            let e = Checkpoint::parse(&text).unwrap_err();
            assert!(
                e.starts_with(expected),
                "{e:?} does not start with {expected:?}"
            );
            assert!(!e.contains('\n'), "{e:?}");
        }
    }
}
