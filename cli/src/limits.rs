//! Limits the command line enforces so that no argument can hang the machine or fill its disk: thread
//! counts are clamped to the logical CPUs, frame counts are capped and checked against the free space of the
//! output directory, generated meshes against the memory available.

use std::path::Path;

/// The most frames one `hinge run` may simulate (about 28 hours of simulated time at 60 frames per second).
pub const MAX_FRAMES: usize = 6_000_000;

/// The machine's logical CPU count (1 when it cannot be determined).
pub fn logical_cpus() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The worker-thread count for `--threads`: the request clamped to `1..=logical CPUs`, or all CPUs when
/// absent. A request above the CPU count returns the count and a one-line warning for stderr.
///
/// # Errors
/// `--threads 0`.
pub fn threads(requested: Option<usize>) -> Result<(usize, Option<String>), String> {
    let cpus = logical_cpus();
    match requested {
        None => Ok((cpus, None)),
        Some(0) => Err("--threads must be at least 1".into()),
        Some(t) if t > cpus => Ok((
            cpus,
            Some(format!(
                "hinge: warning: --threads {t} is more than this machine's {cpus} logical CPUs; using {cpus}"
            )),
        )),
        Some(t) => Ok((t, None)),
    }
}

/// Checks a frame count against [`MAX_FRAMES`].
///
/// # Errors
/// A one-line message naming the cap.
pub fn frames(frames: usize) -> Result<usize, String> {
    match frames {
        0 => Err("--frames must be at least 1".into()),
        f if f > MAX_FRAMES => Err(format!(
            "--frames {f} is more than the limit of {MAX_FRAMES} frames per run"
        )),
        f => Ok(f),
    }
}

/// The size in bytes of one OBJ frame of `n_vertices` vertices and `n_triangles` triangles, as
/// [`hinge_core::obj::write_obj`] writes it (an upper bound: every coordinate at its longest).
pub fn obj_frame_bytes(n_vertices: usize, n_triangles: usize) -> u64 {
    // "v" + three coordinates of `{:.17e}` (at most 25 characters: sign, 18 digits, point, "e-308"), each
    // after a space, + newline.
    let vertex = 1 + 3 * 26 + 1;
    // "f" + three 1-based indices, each after a space, + newline.
    let digits = n_vertices.max(1).ilog10() as usize + 1;
    let face = 1 + 3 * (digits + 1) + 1;
    (n_vertices * vertex + n_triangles * face) as u64
}

/// The size in bytes of one frame file in `format` (an upper bound; PLY is binary: 24 bytes per vertex,
/// 13 per triangle).
pub fn frame_bytes(
    format: hinge_core::meshio::MeshFormat,
    n_vertices: usize,
    n_triangles: usize,
) -> u64 {
    use hinge_core::meshio::MeshFormat;
    match format {
        MeshFormat::Ply => 512 + 24 * n_vertices as u64 + 13 * n_triangles as u64,
        // OFF writes what OBJ writes, with 0-based indices.
        MeshFormat::Obj | MeshFormat::Off => obj_frame_bytes(n_vertices, n_triangles),
        MeshFormat::Stl => 84 + 50 * n_triangles as u64,
    }
}

/// Checks that `bytes` more bytes fit on the file system of `dir` (which must exist).
///
/// # Errors
/// A one-line message with the sizes when they do not fit, or when the free space cannot be read.
pub fn disk_space(dir: &Path, bytes: u64, what: &str) -> Result<(), String> {
    let free = fs4::available_space(dir)
        .map_err(|e| format!("{}: cannot read the free disk space: {e}", dir.display()))?;
    if bytes > free {
        return Err(format!(
            "{}: {what} need about {} but only {} are free (use --no-frames, fewer --frames, or another --out)",
            dir.display(),
            human(bytes),
            human(free)
        ));
    }
    Ok(())
}

/// Peak memory per vertex of `hinge run` and `hinge fit` on a generated mesh or a scene's mesh file, for
/// [`memory`]: measured
/// (`/usr/bin/time -f %M`) 14 KiB on the drape at 401×401 (160 801 vertices, 2.25 GB) and 18 KiB on
/// `shell-drop` at level 6 (40 962 vertices), with a margin.
pub const RUN_BYTES_PER_VERTEX: u64 = 24 * 1024;

/// The same for `hinge stats` (a mesh and its hinge angles): 730 bytes measured on the 2001×2001 grid,
/// with a margin.
pub const STATS_BYTES_PER_VERTEX: u64 = 1024;

/// Peak memory per vertex of the largest `--sizes` grid of `hinge bench` (its rows hold several models and
/// the irregular sheet at once), for [`memory`]: 5.05 GB measured for `hinge bench --sizes 400`
/// (160 801 vertices, 31 KiB each).
pub const BENCH_BYTES_PER_VERTEX: u64 = 32 * 1024;

/// The memory available to a new process (Linux: `MemAvailable` in `/proc/meminfo`), if known.
pub fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Checks that a mesh of `vertices` vertices (generated, or read from a scene's mesh file) fits in the
/// memory available, at `per_vertex` bytes per vertex ([`RUN_BYTES_PER_VERTEX`], …): a size the machine
/// cannot hold is a one-line error, not a process the system kills once it has used all memory. No check
/// where the available memory is unknown.
///
/// # Errors
/// A one-line message with the sizes, naming `what` (the argument that asked for the mesh).
pub fn memory(vertices: u128, per_vertex: u64, what: &str) -> Result<(), String> {
    let Some(available) = available_memory() else {
        return Ok(());
    };
    let need = vertices as f64 * per_vertex as f64;
    if need > available as f64 {
        let count = if vertices < 1_000_000_000_000 {
            vertices.to_string()
        } else {
            format!("{:.2e}", vertices as f64)
        };
        return Err(format!(
            "{what}: a mesh of {count} vertices needs about {} of memory but only {} is available",
            human_f64(need),
            human(available)
        ));
    }
    Ok(())
}

/// `bytes` with a binary unit.
fn human(bytes: u64) -> String {
    human_f64(bytes as f64)
}

/// `bytes` (any size) with a binary unit; beyond EiB in EiB.
fn human_f64(bytes: f64) -> String {
    const UNITS: [&str; 7] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut v = bytes;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if v >= 1e4 {
        format!("{v:.1e} {}", UNITS[u])
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threads_are_clamped_to_the_cpus() {
        let cpus = logical_cpus();
        assert_eq!(threads(None).unwrap(), (cpus, None));
        assert_eq!(threads(Some(1)).unwrap(), (1, None));
        let (t, warning) = threads(Some(100_000)).unwrap();
        assert_eq!(t, cpus);
        let w = warning.unwrap();
        assert!(w.contains("100000") && !w.contains('\n'), "{w}");
        assert!(threads(Some(0)).is_err());
    }

    #[test]
    fn frames_are_capped() {
        assert!(frames(0).is_err());
        assert_eq!(frames(MAX_FRAMES), Ok(MAX_FRAMES));
        assert!(frames(MAX_FRAMES + 1).unwrap_err().contains("limit"));
    }

    #[test]
    fn the_obj_estimate_bounds_a_written_frame() {
        let mesh = hinge_core::grid::unit_grid(30).unwrap();
        let dir = std::env::temp_dir().join(format!("hinge-limits-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("f.obj");
        // Coordinates with many digits: the estimate must still bound the file.
        let x: Vec<_> = mesh
            .positions()
            .iter()
            .map(|p| p * (1.0 / 3.0) - hinge_core::nalgebra::Vector3::repeat(1e-7 / 7.0))
            .collect();
        hinge_core::obj::write_obj(&path, &x, mesh.triangles()).unwrap();
        let written = std::fs::metadata(&path).unwrap().len();
        let estimate = obj_frame_bytes(mesh.n_vertices(), mesh.n_triangles());
        assert!(
            written <= estimate && estimate < 3 * written,
            "{written} vs {estimate}"
        );
        assert!(disk_space(&dir, 1, "frames").is_ok());
        let e = disk_space(&dir, u64::MAX, "frames").unwrap_err();
        assert!(e.contains("only") && !e.contains('\n'), "{e}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
