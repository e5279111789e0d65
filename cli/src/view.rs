//! Pictures of a run: a small z-buffered rasteriser (flat Lambert shading, orthographic camera) that
//! draws the mesh and the obstacles, an animated PNG (APNG) of sampled frames, and `final.png`.
//!
//! The camera is fixed for the whole animation: it looks at the centre of the box that holds every sampled
//! frame and the obstacles (a plane is drawn as a square under that box), from the front-left and 25°
//! above the horizon, with `up = +z`, scaled so that the box fits the picture with a margin.

use std::path::Path;

use hinge_core::nalgebra::Vector3;
use hinge_core::shapes::icosphere;
use hinge_energies::contact::Obstacle;

/// Picture size in pixels.
pub const WIDTH: usize = 400;
/// Picture size in pixels.
pub const HEIGHT: usize = 300;
/// The most frames an animation holds (a run with more is sampled every k-th frame).
pub const MAX_ANIMATION_FRAMES: usize = 60;

/// The colour of the simulated mesh (before shading).
pub const MESH_COLOUR: [f64; 3] = [225.0, 110.0, 50.0];
/// The colour of sphere obstacles (before shading).
pub const SPHERE_COLOUR: [f64; 3] = [70.0, 110.0, 220.0];
/// The colour of plane obstacles (before shading).
pub const PLANE_COLOUR: [f64; 3] = [190.0, 190.0, 190.0];
/// The background.
pub const BACKGROUND: [u8; 3] = [250, 250, 250];

/// Triangles with a colour, ready to rasterise.
struct Layer<'a> {
    positions: &'a [Vector3<f64>],
    triangles: &'a [[usize; 3]],
    colour: [f64; 3],
}

/// An obstacle as a triangle mesh.
#[derive(Debug, Clone)]
pub struct ObstacleMesh {
    /// Vertex positions.
    pub positions: Vec<Vector3<f64>>,
    /// Triangles.
    pub triangles: Vec<[usize; 3]>,
    /// A sphere (else a plane's square).
    pub sphere: bool,
}

/// The subdivision level of the icosahedra that draw sphere obstacles.
const SPHERE_LEVEL: usize = 3;

/// The vertex and triangle counts of an obstacle's mesh (a sphere's, or a plane's square).
pub fn obstacle_mesh_size(sphere: bool) -> (usize, usize) {
    if sphere {
        // Each subdivision quadruples the triangles of the icosahedron: V = 10·4^L + 2, T = 20·4^L.
        let faces = 20 * 4usize.pow(SPHERE_LEVEL as u32);
        (faces / 2 + 2, faces)
    } else {
        (4, 2)
    }
}

/// The obstacles as triangle meshes: spheres as subdivided icosahedra, planes as a square of side
/// `2 · extent` centred under `centre` (the middle of the scene: [`scene_box`]).
///
/// # Errors
/// A message when a sphere cannot be meshed (a non-positive radius).
pub fn obstacle_meshes(
    obstacles: &[Obstacle],
    (centre, extent): (Vector3<f64>, f64),
) -> Result<Vec<ObstacleMesh>, String> {
    let mut out = Vec::new();
    for o in obstacles {
        match *o {
            Obstacle::Sphere {
                center: c,
                radius: r,
            } => {
                let m = icosphere(SPHERE_LEVEL, r).map_err(|e| format!("sphere obstacle: {e}"))?;
                out.push(ObstacleMesh {
                    positions: m.positions().iter().map(|p| p + c).collect(),
                    triangles: m.triangles().to_vec(),
                    sphere: true,
                });
            }
            Obstacle::Plane {
                point: p,
                normal: n,
            } => {
                let n = n.normalize();
                // Two directions in the plane.
                let a = if n.x.abs() < 0.9 {
                    Vector3::x()
                } else {
                    Vector3::y()
                };
                let u = (a - n * n.dot(&a)).normalize() * extent;
                let v = n.cross(&u);
                let o = centre - n * n.dot(&(centre - p));
                out.push(ObstacleMesh {
                    positions: vec![o - u - v, o + u - v, o + u + v, o - u + v],
                    triangles: vec![[0, 1, 2], [0, 2, 3]],
                    sphere: false,
                });
            }
        }
    }
    Ok(out)
}

/// An orthographic camera fitted to a set of points.
struct Camera {
    centre: Vector3<f64>,
    right: Vector3<f64>,
    up: Vector3<f64>,
    forward: Vector3<f64>,
    scale: f64,
}

impl Camera {
    fn fit(points: impl Iterator<Item = Vector3<f64>> + Clone) -> Camera {
        let (azimuth, elevation) = (-60f64.to_radians(), 25f64.to_radians());
        // From the camera towards the scene.
        let forward = -Vector3::new(
            elevation.cos() * azimuth.cos(),
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
        );
        let right = forward.cross(&Vector3::z()).normalize();
        let up = right.cross(&forward);
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for p in points.clone() {
            lo = lo.inf(&p);
            hi = hi.sup(&p);
        }
        if !(lo.x.is_finite() && hi.x.is_finite()) {
            lo = Vector3::repeat(-1.0);
            hi = Vector3::repeat(1.0);
        }
        let centre = (lo + hi) / 2.0;
        let (mut w, mut h) = (0.0_f64, 0.0_f64);
        for p in points {
            let d = p - centre;
            w = w.max(d.dot(&right).abs());
            h = h.max(d.dot(&up).abs());
        }
        // 8% margin on each side.
        let scale =
            ((WIDTH as f64 / 2.0) / w.max(1e-12)).min((HEIGHT as f64 / 2.0) / h.max(1e-12)) * 0.92;
        Camera {
            centre,
            right,
            up,
            forward,
            scale,
        }
    }

    /// Pixel coordinates (x right, y down) and depth (larger is farther).
    fn project(&self, p: &Vector3<f64>) -> [f64; 3] {
        let d = p - self.centre;
        [
            WIDTH as f64 / 2.0 + self.scale * d.dot(&self.right),
            HEIGHT as f64 / 2.0 - self.scale * d.dot(&self.up),
            d.dot(&self.forward),
        ]
    }
}

/// An RGB picture with a depth buffer.
struct Canvas {
    rgb: Vec<u8>,
    depth: Vec<f64>,
}

impl Canvas {
    fn new() -> Self {
        Canvas {
            rgb: BACKGROUND.repeat(WIDTH * HEIGHT),
            depth: vec![f64::INFINITY; WIDTH * HEIGHT],
        }
    }

    fn draw(&mut self, cam: &Camera, layer: &Layer) {
        // Light from the camera's upper left; both faces lit (two-sided).
        let light = (-cam.forward + cam.up * 0.6 - cam.right * 0.4).normalize();
        for t in layer.triangles {
            let [a, b, c] = t.map(|i| layer.positions[i]);
            let n = (b - a).cross(&(c - a));
            let len = n.norm();
            if !(len > 0.0 && len.is_finite()) {
                continue;
            }
            let shade = 0.35 + 0.65 * (n.dot(&light) / len).abs();
            let colour = layer.colour.map(|v| (v * shade).clamp(0.0, 255.0) as u8);
            let [p, q, r] = [a, b, c].map(|x| cam.project(&x));
            self.fill(p, q, r, colour);
        }
    }

    fn fill(&mut self, p: [f64; 3], q: [f64; 3], r: [f64; 3], colour: [u8; 3]) {
        let area = (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
        if !(area.abs() > 1e-12) || !area.is_finite() {
            return;
        }
        let x0 = p[0].min(q[0]).min(r[0]).floor().max(0.0) as usize;
        let x1 = (p[0].max(q[0]).max(r[0]).ceil().min(WIDTH as f64 - 1.0)).max(0.0) as usize;
        let y0 = p[1].min(q[1]).min(r[1]).floor().max(0.0) as usize;
        let y1 = (p[1].max(q[1]).max(r[1]).ceil().min(HEIGHT as f64 - 1.0)).max(0.0) as usize;
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (sx, sy) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((q[0] - sx) * (r[1] - sy) - (q[1] - sy) * (r[0] - sx)) / area;
                let w1 = ((r[0] - sx) * (p[1] - sy) - (r[1] - sy) * (p[0] - sx)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p[2] + w1 * q[2] + w2 * r[2];
                let k = y * WIDTH + x;
                if z < self.depth[k] {
                    self.depth[k] = z;
                    self.rgb[3 * k..3 * k + 3].copy_from_slice(&colour);
                }
            }
        }
    }
}

/// Renders `frames` (positions of the mesh `triangles`) with the obstacle meshes from one camera fitted
/// to all of them: one RGB picture ([`WIDTH`] × [`HEIGHT`]) per frame. `obstacles` holds the obstacles of
/// each frame (moving obstacles), or one set drawn in every frame.
pub fn render(
    frames: &[Vec<Vector3<f64>>],
    triangles: &[[usize; 3]],
    obstacles: &[Vec<ObstacleMesh>],
) -> Vec<Vec<u8>> {
    let layers: Vec<Vec<Layer>> = obstacles
        .iter()
        .map(|set| {
            set.iter()
                .map(|o| Layer {
                    colour: if o.sphere {
                        SPHERE_COLOUR
                    } else {
                        PLANE_COLOUR
                    },
                    positions: &o.positions,
                    triangles: &o.triangles,
                })
                .collect()
        })
        .collect();
    // The camera sees every frame and the spheres (planes are unbounded: only their square under the mesh).
    let points = frames.iter().flatten().copied().chain(
        layers
            .iter()
            .flatten()
            .filter(|l| l.colour == SPHERE_COLOUR)
            .flat_map(|l| l.positions.iter().copied()),
    );
    let cam = Camera::fit(points);
    let mut pictures = Vec::with_capacity(frames.len());
    for (i, x) in frames.iter().enumerate() {
        let mut canvas = Canvas::new();
        let set = if layers.len() == 1 {
            layers.first()
        } else {
            layers.get(i)
        };
        for l in set.into_iter().flatten() {
            canvas.draw(&cam, l);
        }
        canvas.draw(
            &cam,
            &Layer {
                positions: x,
                triangles,
                colour: MESH_COLOUR,
            },
        );
        pictures.push(canvas.rgb);
    }
    pictures
}

/// The centre of the box holding every frame, and the half-diagonal of that box (at least 1e-3).
pub fn scene_box(frames: &[Vec<Vector3<f64>>]) -> (Vector3<f64>, f64) {
    let (mut lo, mut hi) = (
        Vector3::repeat(f64::INFINITY),
        Vector3::repeat(f64::NEG_INFINITY),
    );
    for p in frames.iter().flatten() {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if !(lo.x.is_finite() && hi.x.is_finite()) {
        return (Vector3::zeros(), 1.0);
    }
    ((lo + hi) / 2.0, ((hi - lo).norm() / 2.0).max(1e-3))
}

fn encoder(
    file: &mut std::io::BufWriter<std::fs::File>,
) -> png::Encoder<'_, &mut std::io::BufWriter<std::fs::File>> {
    let mut enc = png::Encoder::new(file, WIDTH as u32, HEIGHT as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc
}

/// Writes `pictures` as an animated PNG, each shown `delay_ms` milliseconds, looping.
///
/// # Errors
/// A one-line message naming the file.
pub fn write_apng(path: &Path, pictures: &[Vec<u8>], delay_ms: u16) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    if pictures.is_empty() {
        return Err(err(&"no frames to animate"));
    }
    let file = std::fs::File::create(path).map_err(|e| err(&e))?;
    let mut file = std::io::BufWriter::new(file);
    let mut enc = encoder(&mut file);
    enc.set_animated(pictures.len() as u32, 0)
        .map_err(|e| err(&e))?;
    enc.set_frame_delay(delay_ms, 1000).map_err(|e| err(&e))?;
    let mut writer = enc.write_header().map_err(|e| err(&e))?;
    for p in pictures {
        writer.write_image_data(p).map_err(|e| err(&e))?;
    }
    writer.finish().map_err(|e| err(&e))
}

/// Writes one picture as a PNG.
///
/// # Errors
/// A one-line message naming the file.
pub fn write_png(path: &Path, picture: &[u8]) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let file = std::fs::File::create(path).map_err(|e| err(&e))?;
    let mut file = std::io::BufWriter::new(file);
    let enc = encoder(&mut file);
    let mut writer = enc.write_header().map_err(|e| err(&e))?;
    writer.write_image_data(picture).map_err(|e| err(&e))?;
    writer.finish().map_err(|e| err(&e))
}

/// Writes the obstacle meshes (as drawn) to one OBJ file.
///
/// # Errors
/// A one-line message naming the file.
pub fn write_obstacles(path: &Path, meshes: &[ObstacleMesh]) -> Result<(), String> {
    let (mut x, mut t) = (Vec::new(), Vec::new());
    for o in meshes {
        let base = x.len();
        x.extend_from_slice(&o.positions);
        t.extend(o.triangles.iter().map(|f| f.map(|i| i + base)));
    }
    hinge_core::obj::write_obj(path, &x, &t).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obstacle_mesh_sizes_are_those_drawn() {
        let obstacles = [
            Obstacle::Sphere {
                center: Vector3::zeros(),
                radius: 0.5,
            },
            Obstacle::Plane {
                point: Vector3::zeros(),
                normal: Vector3::z(),
            },
        ];
        let meshes = obstacle_meshes(&obstacles, (Vector3::zeros(), 1.0)).unwrap();
        for (m, sphere) in meshes.iter().zip([true, false]) {
            assert_eq!(
                (m.positions.len(), m.triangles.len()),
                obstacle_mesh_size(sphere)
            );
        }
    }

    /// A square of side 2 through `centre`, facing the camera's direction `towards`.
    fn square(centre: Vector3<f64>, towards: Vector3<f64>) -> (Vec<Vector3<f64>>, Vec<[usize; 3]>) {
        let n = towards.normalize();
        let u = n.cross(&Vector3::z()).normalize();
        let v = n.cross(&u);
        let x = vec![
            centre - u - v,
            centre + u - v,
            centre + u + v,
            centre - u + v,
        ];
        (x, vec![[0, 1, 2], [0, 2, 3]])
    }

    fn centre_pixel(rgb: &[u8]) -> [u8; 3] {
        let k = 3 * (HEIGHT / 2 * WIDTH + WIDTH / 2);
        [rgb[k], rgb[k + 1], rgb[k + 2]]
    }

    #[test]
    fn the_nearer_surface_is_drawn() {
        let cam = Camera::fit([Vector3::zeros()].into_iter());
        let sphere = [Obstacle::Sphere {
            center: Vector3::zeros(),
            radius: 0.5,
        }];
        // A square between the camera and the sphere hides it; behind the sphere it is hidden.
        for (offset, mesh_in_front) in [(-3.0, true), (3.0, false)] {
            let (x, t) = square(cam.forward * offset, cam.forward);
            let frames = [x];
            let meshes = obstacle_meshes(&sphere, scene_box(&frames)).unwrap();
            let pictures = render(&frames, &t, std::slice::from_ref(&meshes));
            let [r, g, b] = centre_pixel(&pictures[0]).map(i32::from);
            if mesh_in_front {
                assert!(
                    r > g + 40 && r > b + 40,
                    "mesh colour expected: {r} {g} {b}"
                );
            } else {
                assert!(b > r + 40, "sphere colour expected: {r} {g} {b}");
            }
            // The background stays in the corners (the fit leaves a margin).
            assert_eq!(&pictures[0][..3], &BACKGROUND);
        }
    }

    #[test]
    fn the_camera_fits_every_point_in_the_picture() {
        let points = [
            Vector3::new(-3.0, 1.0, 0.0),
            Vector3::new(2.0, -1.0, 4.0),
            Vector3::new(0.5, 7.0, -2.0),
        ];
        let cam = Camera::fit(points.iter().copied());
        for p in points {
            let [x, y, _] = cam.project(&p);
            assert!(
                x > 0.0 && x < WIDTH as f64 && y > 0.0 && y < HEIGHT as f64,
                "{x} {y}"
            );
        }
    }
}
