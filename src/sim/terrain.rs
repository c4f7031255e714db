//! Terrain generators (seed report §3.1): flat ground, Perlin bumps, linear slopes, a heightmap
//! from a 16-bit PNG (all heightfields), and a steel pipe and a floor-to-wall fillet (trimeshes,
//! since a heightfield cannot hold a vertical or overhanging surface).
//!
//! One idea in one file (over 500 lines): every generator is a few lines over the shared grid,
//! placement and unrolling code below, which is what makes the terrains agree with each other.
//!
//! # Frame and placement
//! World frame (right-handed): Y up, robot forward +X, +Z to the robot's right, metres. The robot starts near the origin, so:
//! - flat, Perlin, slope and heightmap terrains are centred on the origin in X/Z and shifted
//!   vertically so that the surface passes through height 0 at (x, z) = (0, 0);
//! - the pipe's top line lies at height 0 right under the origin;
//! - the wall's floor is at height 0 and its vertical face stands at x = `wall_distance_m`.
//!
//! # Heightfield layout
//! [`TerrainGeometry::HeightField`] stores `rows × cols` heights **row-major**: row `i` advances
//! along **Z**, column `j` along **X** (this is parry's convention: its `Array2` is column-major
//! with rows = Z, [`TerrainGeometry::collider`] converts). Sample `(i, j)` sits at
//! `x = (-0.5 + j / (cols - 1)) · scale.x`, `z = (-0.5 + i / (rows - 1)) · scale.z`, and its
//! height is `heights[i * cols + j] · scale.y` (`scale.y` is always 1, heights are metres).
//! Each cell is split along the diagonal from (x0, z1) to (x1, z0), as parry does by default;
//! [`TerrainGeometry::height_at`] interpolates on those same triangles.
//!
//! `resolution` is the number of **cells** per side (a power of two), so a heightfield has
//! `resolution + 1` samples per side and the centre of the terrain is a grid vertex.
//!
//! # Determinism
//! Everything is a pure function of the spec, the seed and (for heightmaps) the file bytes.
//! Perlin noise comes from `noise::Perlin` seeded from the scenario seed; no other randomness.

use std::path::{Path, PathBuf};

use noise::{NoiseFn, Perlin};
use rapier3d::math::{Real, Vector};
use rapier3d::prelude::{Array2, ColliderBuilder, HeightFieldFlags, TriMesh, TriMeshFlags};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// The largest accepted heightfield `resolution` (cells per side): 8192² cells are already
/// ~270 MB of heights.
pub const MAX_RESOLUTION: u32 = 8192;

/// Horizontal axis of a pipe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Z,
}

/// A terrain as written in a scenario file (`kind = "flat"`, `"perlin"`, ...).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum TerrainSpec {
    /// A flat square of side `size_m` at height 0 (a single-cell heightfield).
    Flat { size_m: f32 },
    /// Perlin bumps on a square of side `size_m` with `resolution` cells per side (a power of two).
    ///
    /// As in the seed, each sample is a fraction `f ∈ [0, 1]` of `max_height_m`:
    /// `f(x, z) = clamp((perlin(100·x/noise_scale + ox, 100·z/noise_scale + oz) + 1) / 2, 0, 1)`
    /// with `x`, `z` in metres, `perlin` = `noise::Perlin` (one octave, range [−1, 1]) seeded with
    /// the low 32 bits of SplitMix64 #1 of the scenario seed, and `(ox, oz) ∈ [0, 256)²` taken
    /// from SplitMix64 #2 and #3 (top 24 bits / 65536). So `noise_scale`
    /// is the Perlin lattice period in **centimetres**: the seed's 100 gives bumps on a 1 m
    /// lattice, its 1000 a ten times smoother 10 m lattice. The terrain at a given (x, z) does not
    /// depend on `size_m` or `resolution` (they only crop and sample it). Heights are then
    /// `max_height_m · (f(x, z) − f(0, 0))`, so the centre is at 0 and every height lies in
    /// `[-max_height_m, max_height_m]` with a peak-to-peak of at most `max_height_m`.
    Perlin { size_m: f32, resolution: u32, max_height_m: f32, noise_scale: f32 },
    /// A plane `y = tan(slope_x_deg)·x + tan(slope_z_deg)·z` (through the origin, rising towards
    /// +X for a positive `slope_x_deg`) on a square of side `size_m`; angles in (−90°, 90°).
    Slope { size_m: f32, resolution: u32, slope_x_deg: f32, slope_z_deg: f32 },
    /// One smooth bump (a raised cosine) of `height_m` and base radius `radius_m` centred at
    /// (`x_m`, `z_m`) on flat ground; `height_m < 0` makes a dent. For magnet and rocker tests.
    Bump { size_m: f32, resolution: u32, height_m: f32, radius_m: f32, x_m: f32, z_m: f32 },
    /// A one-sided step: ground raised by `height_m` where x ≥ `x_m` and z ≥ `z_from_m` (the
    /// robot's right side when `z_from_m` is 0: +z is to the right of a robot facing +x), with a ramp one cell wide. For rocker tests.
    Step { size_m: f32, resolution: u32, height_m: f32, x_m: f32, z_from_m: f32 },
    /// The outside of a steel pipe (cylinder of `radius_m`, `length_m` long, centred on the
    /// origin along its horizontal `axis`), top line at height 0 under the origin, so its axis is
    /// at y = −`radius_m`. A `segments`-gon (≥ 3) inscribed in the circle with a vertex at the
    /// top, both ends capped (a closed mesh, outward normals).
    Pipe { radius_m: f32, length_m: f32, axis: Axis, segments: u32 },
    /// A floor at height 0 from x = −max(`wall_distance_m`, `width_m`/2) curving up through a
    /// quarter-circle fillet of `fillet_radius_m` (`segments` facets; 0 = sharp corner) into a
    /// vertical face at x = `wall_distance_m` rising to `wall_height_m`; `width_m` along Z centred
    /// on 0. One-sided sheet, normals facing the robot (+Y on the floor, −X on the wall).
    /// Requires `fillet_radius_m ≤ wall_distance_m` (the floor under the origin is flat) and
    /// `fillet_radius_m ≤ wall_height_m`.
    Wall { wall_distance_m: f32, wall_height_m: f32, width_m: f32, fillet_radius_m: f32, segments: u32 },
    /// A 16-bit grayscale PNG (`path` relative to the scenario file's folder): pixel column →
    /// X, pixel row → Z (row 0 at the smallest Z, i.e. the image seen from above with +X to the
    /// right), value `v` → `max_height_m · v / 65535`, then shifted so the centre is at 0.
    /// `size_m` is the X extent; Z extent = `size_m · (height − 1) / (width − 1)` (square cells).
    Heightmap { path: PathBuf, size_m: f32, max_height_m: f32 },
}

/// Generated terrain geometry, ready to become a collider.
#[derive(Debug, Clone, PartialEq)]
pub enum TerrainGeometry {
    /// `heights[i * cols + j]`: row `i` along Z, column `j` along X (see the module docs);
    /// `scale` = (total X extent, 1, total Z extent), centred on the origin, as rapier expects.
    HeightField { heights: Vec<f32>, rows: usize, cols: usize, scale: Vector },
    /// Triangles wound counter-clockwise seen from the side the robot drives on.
    TriMesh { vertices: Vec<Vector>, indices: Vec<[u32; 3]> },
}

/// Why a terrain could not be generated.
#[derive(Debug, Error)]
pub enum TerrainError {
    #[error("terrain resolution {resolution} is not a power of two (use e.g. 64, 128, 256)")]
    ResolutionNotPowerOfTwo { resolution: u32 },
    #[error("terrain resolution {resolution} is larger than the maximum {MAX_RESOLUTION}")]
    ResolutionTooLarge { resolution: u32 },
    #[error("terrain {field} must be positive and finite, got {value}")]
    NotPositive { field: &'static str, value: f32 },
    #[error("terrain {field} = {value} is invalid: {reason}")]
    Invalid { field: &'static str, value: f32, reason: &'static str },
    #[error("cannot read heightmap {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("heightmap {path} is not a valid PNG: {source}")]
    Png { path: PathBuf, source: png::DecodingError },
    #[error("heightmap {path} is {bit_depth}-bit {color_type}; expected a 16-bit grayscale PNG")]
    NotGray16 { path: PathBuf, color_type: String, bit_depth: u8 },
    #[error("heightmap {path} is {width}×{height} pixels; it needs at least 2×2")]
    HeightmapTooSmall { path: PathBuf, width: u32, height: u32 },
    #[error("terrain mesh is invalid: {0}")]
    Mesh(String),
}

/// Generate the geometry of `spec`. `seed` drives the Perlin noise; `base_dir` is the folder
/// relative heightmap paths are resolved against (the scenario file's folder).
pub fn generate(spec: &TerrainSpec, seed: u64, base_dir: &Path) -> Result<TerrainGeometry, TerrainError> {
    let geometry = match *spec {
        TerrainSpec::Flat { size_m } => {
            positive("size_m", size_m)?;
            TerrainGeometry::HeightField { heights: vec![0.0; 4], rows: 2, cols: 2, scale: Vector::new(size_m, 1.0, size_m) }
        }
        TerrainSpec::Perlin { size_m, resolution, max_height_m, noise_scale } => {
            positive("size_m", size_m)?;
            check_resolution(resolution)?;
            positive("max_height_m", max_height_m)?;
            positive("noise_scale", noise_scale)?;
            perlin(size_m, resolution, max_height_m, noise_scale, seed)
        }
        TerrainSpec::Slope { size_m, resolution, slope_x_deg, slope_z_deg } => {
            positive("size_m", size_m)?;
            check_resolution(resolution)?;
            let tx = slope_tan("slope_x_deg", slope_x_deg)?;
            let tz = slope_tan("slope_z_deg", slope_z_deg)?;
            grid(size_m, size_m, resolution as usize + 1, resolution as usize + 1, |x, z| tx * x + tz * z)
        }
        TerrainSpec::Bump { size_m, resolution, height_m, radius_m, x_m, z_m } => {
            positive("size_m", size_m)?;
            check_resolution(resolution)?;
            positive("radius_m", radius_m)?;
            let (cx, cz, h, r) = (f64::from(x_m), f64::from(z_m), f64::from(height_m), f64::from(radius_m));
            let n = resolution as usize + 1;
            level_to_corner(grid(size_m, size_m, n, n, |x, z| {
                let d = ((x - cx).powi(2) + (z - cz).powi(2)).sqrt();
                if d < r { h * 0.5 * (1.0 + (std::f64::consts::PI * d / r).cos()) } else { 0.0 }
            }))
        }
        TerrainSpec::Step { size_m, resolution, height_m, x_m, z_from_m } => {
            positive("size_m", size_m)?;
            check_resolution(resolution)?;
            let n = resolution as usize + 1;
            let (x0, z0, h) = (f64::from(x_m), f64::from(z_from_m), f64::from(height_m));
            level_to_corner(grid(size_m, size_m, n, n, |x, z| if x >= x0 && z >= z0 { h } else { 0.0 }))
        }
        TerrainSpec::Pipe { radius_m, length_m, axis, segments } => {
            positive("radius_m", radius_m)?;
            positive("length_m", length_m)?;
            if segments < 3 {
                return Err(invalid("segments", segments as f32, "a pipe needs at least 3 segments"));
            }
            pipe(radius_m, length_m, axis, segments as usize)
        }
        TerrainSpec::Wall { wall_distance_m, wall_height_m, width_m, fillet_radius_m, segments } => {
            positive("wall_distance_m", wall_distance_m)?;
            positive("wall_height_m", wall_height_m)?;
            positive("width_m", width_m)?;
            if !(fillet_radius_m >= 0.0 && fillet_radius_m.is_finite()) {
                return Err(invalid("fillet_radius_m", fillet_radius_m, "must be ≥ 0 and finite"));
            }
            if fillet_radius_m > wall_distance_m {
                return Err(invalid("fillet_radius_m", fillet_radius_m, "must not exceed wall_distance_m"));
            }
            if fillet_radius_m > wall_height_m {
                return Err(invalid("fillet_radius_m", fillet_radius_m, "must not exceed wall_height_m"));
            }
            if fillet_radius_m > 0.0 && segments == 0 {
                return Err(invalid("segments", 0.0, "a fillet needs at least 1 segment"));
            }
            wall(wall_distance_m, wall_height_m, width_m, fillet_radius_m, segments as usize)
        }
        TerrainSpec::Heightmap { ref path, size_m, max_height_m } => {
            positive("size_m", size_m)?;
            positive("max_height_m", max_height_m)?;
            heightmap(&base_dir.join(path), size_m, max_height_m)?
        }
    };
    if let TerrainGeometry::TriMesh { vertices, indices } = &geometry {
        // Validate once here so that `collider()` cannot fail on generated geometry.
        TriMesh::with_flags(vertices.clone(), indices.clone(), TRIMESH_FLAGS).map_err(|e| TerrainError::Mesh(e.to_string()))?;
    }
    Ok(geometry)
}

/// Trimesh flags: one-sided internal-edge fixing (contacts from behind a triangle are dropped,
/// so the winding must face the robot) and oriented pseudo-normals for inside/outside tests.
const TRIMESH_FLAGS: TriMeshFlags = TriMeshFlags::FIX_INTERNAL_EDGES.union(TriMeshFlags::ORIENTED);

impl TerrainGeometry {
    /// A fixed-terrain collider: heightfield with `FIX_INTERNAL_EDGES`, or trimesh with
    /// `FIX_INTERNAL_EDGES | ORIENTED`. Friction and groups are left at their defaults.
    ///
    /// # Panics
    /// If the geometry is inconsistent (`heights.len() != rows · cols`, fewer than 2 rows or
    /// columns, an empty or out-of-range index buffer). Geometry from [`generate`] never is.
    pub fn collider(&self) -> ColliderBuilder {
        match self {
            TerrainGeometry::HeightField { heights, rows, cols, scale } => {
                assert_eq!(heights.len(), rows * cols, "heightfield heights must hold rows × cols values");
                let array = Array2::from_fn(*rows, *cols, |i, j| heights[i * cols + j]);
                ColliderBuilder::heightfield_with_flags(array, *scale, HeightFieldFlags::FIX_INTERNAL_EDGES)
            }
            TerrainGeometry::TriMesh { vertices, indices } => {
                ColliderBuilder::trimesh_with_flags(vertices.clone(), indices.clone(), TRIMESH_FLAGS).expect("terrain trimesh is valid (checked by generate)")
            }
        }
    }

    /// Height of the surface at (x, z) for heightfields, interpolated on the collider's own
    /// triangles; `None` outside the heightfield or for trimeshes.
    pub fn height_at(&self, x: f32, z: f32) -> Option<f32> {
        let TerrainGeometry::HeightField { heights, rows, cols, scale } = self else {
            return None;
        };
        let (rows, cols) = (*rows, *cols);
        // Same arithmetic as parry's HeightField: unit square, then scaled.
        let (ux, uz) = (x / scale.x, z / scale.z);
        if !(-0.5..=0.5).contains(&ux) || !(-0.5..=0.5).contains(&uz) {
            return None;
        }
        let cell_w = 1.0 / (cols as Real - 1.0);
        let cell_h = 1.0 / (rows as Real - 1.0);
        let j = (((ux + 0.5) / cell_w).floor() as usize).min(cols - 2);
        let i = (((uz + 0.5) / cell_h).floor() as usize).min(rows - 2);
        let u = ((ux - (-0.5 + cell_w * j as Real)) / cell_w).clamp(0.0, 1.0);
        let v = ((uz - (-0.5 + cell_h * i as Real)) / cell_h).clamp(0.0, 1.0);
        let h = |i: usize, j: usize| heights[i * cols + j];
        let (y00, y01, y10, y11) = (h(i, j), h(i, j + 1), h(i + 1, j), h(i + 1, j + 1));
        // parry's triangles: (x0,z0) (x0,z1) (x1,z0) and (x0,z1) (x1,z1) (x1,z0).
        let y = if u + v <= 1.0 { y00 + u * (y01 - y00) + v * (y10 - y00) } else { y11 + (1.0 - u) * (y10 - y11) + (1.0 - v) * (y01 - y11) };
        Some(y * scale.y)
    }

    /// 64-bit FNV-1a digest of the geometry (kind, dimensions and every f32's bits), for
    /// comparing terrains in tests and logs.
    pub fn digest(&self) -> u64 {
        let mut d = Fnv::new();
        match self {
            TerrainGeometry::HeightField { heights, rows, cols, scale } => {
                d.bytes(&[0]);
                d.u64(*rows as u64);
                d.u64(*cols as u64);
                d.vector(*scale);
                heights.iter().for_each(|h| d.f32(*h));
            }
            TerrainGeometry::TriMesh { vertices, indices } => {
                d.bytes(&[1]);
                d.u64(vertices.len() as u64);
                vertices.iter().for_each(|v| d.vector(*v));
                d.u64(indices.len() as u64);
                indices.iter().flatten().for_each(|i| d.bytes(&i.to_le_bytes()));
            }
        }
        d.0
    }
}

struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 = (self.0 ^ u64::from(*b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.bytes(&v.to_bits().to_le_bytes());
    }
    fn vector(&mut self, v: Vector) {
        [v.x, v.y, v.z].into_iter().for_each(|c| self.f32(c));
    }
}

fn positive(field: &'static str, value: f32) -> Result<(), TerrainError> {
    if value > 0.0 && value.is_finite() { Ok(()) } else { Err(TerrainError::NotPositive { field, value }) }
}

fn invalid(field: &'static str, value: f32, reason: &'static str) -> TerrainError {
    TerrainError::Invalid { field, value, reason }
}

fn check_resolution(resolution: u32) -> Result<(), TerrainError> {
    if !resolution.is_power_of_two() {
        Err(TerrainError::ResolutionNotPowerOfTwo { resolution })
    } else if resolution > MAX_RESOLUTION {
        Err(TerrainError::ResolutionTooLarge { resolution })
    } else {
        Ok(())
    }
}

fn slope_tan(field: &'static str, deg: f32) -> Result<f64, TerrainError> {
    if deg.is_finite() && deg.abs() < 90.0 { Ok(f64::from(deg).to_radians().tan()) } else { Err(invalid(field, deg, "a slope angle must lie strictly between -90 and 90 degrees")) }
}

/// A heightfield of `rows × cols` samples over `size_x × size_z` metres, sampling `f(x, z)` at
/// the exact vertex positions the collider uses, then shifted so that `height_at(0, 0) == 0`.
fn grid(size_x: f32, size_z: f32, rows: usize, cols: usize, f: impl Fn(f64, f64) -> f64) -> TerrainGeometry {
    let scale = Vector::new(size_x, 1.0, size_z);
    let (cell_w, cell_h) = (1.0 / (cols as Real - 1.0), 1.0 / (rows as Real - 1.0));
    let mut heights = Vec::with_capacity(rows * cols);
    for i in 0..rows {
        let z = (-0.5 + cell_h * i as Real) * size_z;
        for j in 0..cols {
            let x = (-0.5 + cell_w * j as Real) * size_x;
            heights.push(f(f64::from(x), f64::from(z)) as f32);
        }
    }
    recentre(TerrainGeometry::HeightField { heights, rows, cols, scale })
}

/// Shift a heightfield so that its (−x, −z) corner, flat ground for bumps and steps, is at 0:
/// `grid` centres on the origin, which may lie on the feature.
fn level_to_corner(mut geometry: TerrainGeometry) -> TerrainGeometry {
    if let TerrainGeometry::HeightField { heights, .. } = &mut geometry
        && let Some(&corner) = heights.first()
    {
        heights.iter_mut().for_each(|h| *h -= corner);
    }
    geometry
}

fn recentre(mut geometry: TerrainGeometry) -> TerrainGeometry {
    let centre = geometry.height_at(0.0, 0.0).unwrap_or(0.0);
    if let TerrainGeometry::HeightField { heights, .. } = &mut geometry
        && centre != 0.0
    {
        heights.iter_mut().for_each(|h| *h -= centre);
    }
    geometry
}

/// SplitMix64: spreads the 64-bit scenario seed over the Perlin permutation seed and offsets.
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

fn perlin(size_m: f32, resolution: u32, max_height_m: f32, noise_scale: f32, seed: u64) -> TerrainGeometry {
    let mut state = seed;
    let noise = Perlin::new(splitmix64(&mut state) as u32);
    // Offsets in [0, 256) lattice units (the permutation table's period) with 1/65536 steps:
    // all 64 seed bits matter and the origin is not pinned to a lattice point (where Perlin = 0).
    let mut offset = || (splitmix64(&mut state) >> 40) as f64 / 65536.0;
    let (ox, oz) = (offset(), offset());
    let k = 100.0 / f64::from(noise_scale);
    let fraction = |x: f64, z: f64| ((noise.get([k * x + ox, k * z + oz]) + 1.0) / 2.0).clamp(0.0, 1.0);
    let samples = resolution as usize + 1;
    let max = f64::from(max_height_m);
    grid(size_m, size_m, samples, samples, |x, z| max * fraction(x, z))
}

fn pipe(radius: f32, length: f32, axis: Axis, segments: usize) -> TerrainGeometry {
    // Built along X, then turned a quarter about Y for a Z axis (a rotation keeps the winding).
    let (r, half) = (f64::from(radius), f64::from(length) / 2.0);
    let mut vertices = Vec::with_capacity(2 * segments + 2);
    for x in [-half, half] {
        for k in 0..segments {
            // θ from the top: k = 0 is exactly (y, z) = (0, 0).
            let theta = std::f64::consts::TAU * k as f64 / segments as f64;
            vertices.push([x, -r + r * theta.cos(), r * theta.sin()]);
        }
    }
    vertices.push([-half, -r, 0.0]);
    vertices.push([half, -r, 0.0]);
    let (a, b) = (|k: usize| (k % segments) as u32, |k: usize| (segments + k % segments) as u32);
    let (ca, cb) = (2 * segments as u32, 2 * segments as u32 + 1);
    let mut indices = Vec::with_capacity(4 * segments);
    for k in 0..segments {
        indices.push([a(k), b(k + 1), b(k)]);
        indices.push([a(k), a(k + 1), b(k + 1)]);
        indices.push([cb, b(k), b(k + 1)]);
        indices.push([ca, a(k + 1), a(k)]);
    }
    let vertices = vertices
        .into_iter()
        .map(|[x, y, z]| match axis {
            Axis::X => Vector::new(x as f32, y as f32, z as f32),
            Axis::Z => Vector::new(z as f32, y as f32, -x as f32),
        })
        .collect();
    TerrainGeometry::TriMesh { vertices, indices }
}

fn wall(distance: f32, height: f32, width: f32, fillet: f32, segments: usize) -> TerrainGeometry {
    let profile = wall_profile(distance, height, width, fillet, segments);
    let n = profile.len();
    let half = width / 2.0;
    let vertices = [-half, half].into_iter().flat_map(|z| profile.iter().map(move |[x, y]| Vector::new(*x as f32, *y as f32, z))).collect();
    let (a, b) = (|k: usize| k as u32, |k: usize| (n + k) as u32);
    let indices = (0..n - 1).flat_map(|k| [[a(k), b(k + 1), a(k + 1)], [a(k), b(k), b(k + 1)]]).collect();
    TerrainGeometry::TriMesh { vertices, indices }
}

/// The wall terrain's (x, y) profile, floor start to wall top: the polyline its mesh extrudes
/// along Z.
fn wall_profile(distance: f32, height: f32, width: f32, fillet: f32, segments: usize) -> Vec<[f64; 2]> {
    let (d, h, r) = (f64::from(distance), f64::from(height), f64::from(fillet));
    let mut profile = vec![[-(d.max(f64::from(width) / 2.0)), 0.0]];
    if r > 0.0 {
        // Quarter circle centred (d − r, r), from straight below the centre to straight right of it.
        profile.push([d - r, 0.0]);
        for k in 1..segments {
            let phi = std::f64::consts::FRAC_PI_2 * k as f64 / segments as f64;
            profile.push([d - r + r * phi.sin(), r - r * phi.cos()]);
        }
        profile.push([d, r]);
    } else {
        profile.push([d, 0.0]);
    }
    if h > r {
        profile.push([d, h]);
    }
    profile
}

/// A terrain that is a profile extruded along Z (the floor-to-wall terrain), laid flat: a point
/// (u, z) of the unrolled sheet is `u` metres along the profile, counted so that the floor keeps
/// its own x (u = x wherever the floor is), and z across. A weld line painted across floor,
/// fillet and wall is written in these coordinates: `[[0, 0], [2, 0]]` on a wall 0.5 m ahead runs
/// 0.5 m over the floor, round the fillet and on up the wall. Points lie exactly on the mesh's
/// facets, so a faceted fillet carries a faceted line.
#[derive(Debug, Clone, PartialEq)]
pub struct UnrolledProfile {
    /// Profile vertices (x, y), floor start first.
    vertices: Vec<[f32; 2]>,
    /// u of each vertex.
    u: Vec<f32>,
    half_width_m: f32,
}

impl UnrolledProfile {
    /// The unrolled sheet of a wall terrain; `None` for every other kind (those are draped from
    /// above instead).
    pub fn of(spec: &TerrainSpec) -> Option<Self> {
        let TerrainSpec::Wall { wall_distance_m, wall_height_m, width_m, fillet_radius_m, segments } = *spec else { return None };
        let vertices: Vec<[f32; 2]> = wall_profile(wall_distance_m, wall_height_m, width_m, fillet_radius_m, segments as usize).into_iter().map(|[x, y]| [x as f32, y as f32]).collect();
        let mut u = vec![vertices.first()?[0]];
        for w in vertices.windows(2) {
            let last = u[u.len() - 1];
            u.push(last + (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]));
        }
        Some(Self { vertices, u, half_width_m: width_m / 2.0 })
    }

    /// The point of the surface at unrolled (u, z) and its normal (toward the robot's side), or
    /// `None` off the sheet.
    pub fn point(&self, u: f32, z: f32) -> Option<(Vector, Vector)> {
        if !(u.is_finite() && z.is_finite()) || z.abs() > self.half_width_m {
            return None;
        }
        let (first, last) = (self.u[0], self.u[self.u.len() - 1]);
        if !(first..=last).contains(&u) {
            return None;
        }
        // The segment holding u (the last one for u at the top).
        let k = self.u.windows(2).position(|w| u <= w[1]).unwrap_or(self.u.len() - 2);
        let ([x0, y0], [x1, y1]) = (self.vertices[k], self.vertices[k + 1]);
        let length = (self.u[k + 1] - self.u[k]).max(f32::EPSILON);
        let s = ((u - self.u[k]) / length).clamp(0.0, 1.0);
        let (dx, dy) = ((x1 - x0) / length, (y1 - y0) / length);
        // The profile runs floor → wall; its left (the robot's side) is (−dy, dx).
        Some((Vector::new(x0 + s * (x1 - x0), y0 + s * (y1 - y0), z), Vector::new(-dy, dx, 0.0)))
    }

    /// The sheet's (u, z) of the surface point nearest `p` (a point in the world near the
    /// surface, such as the robot's centre).
    pub fn unroll(&self, p: Vector) -> [f32; 2] {
        let mut best = (f32::INFINITY, self.u[0]);
        for (k, w) in self.vertices.windows(2).enumerate() {
            let ([x0, y0], [x1, y1]) = (w[0], w[1]);
            let (dx, dy) = (x1 - x0, y1 - y0);
            let length2 = (dx * dx + dy * dy).max(f32::EPSILON);
            let s = (((p.x - x0) * dx + (p.y - y0) * dy) / length2).clamp(0.0, 1.0);
            let distance2 = (x0 + s * dx - p.x).powi(2) + (y0 + s * dy - p.y).powi(2);
            if distance2 < best.0 {
                best = (distance2, self.u[k] + s * (self.u[k + 1] - self.u[k]));
            }
        }
        [best.1, p.z]
    }

    /// The unit direction of increasing u at `u` (along the profile, in the x-y plane).
    pub fn along(&self, u: f32) -> Option<Vector> {
        let (_, normal) = self.point(u, 0.0)?;
        Some(Vector::new(normal.y, -normal.x, 0.0))
    }
}

fn heightmap(path: &Path, size_m: f32, max_height_m: f32) -> Result<TerrainGeometry, TerrainError> {
    let file = std::fs::File::open(path).map_err(|source| TerrainError::Io { path: path.to_owned(), source })?;
    let png_error = |source| TerrainError::Png { path: path.to_owned(), source };
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().map_err(png_error)?;
    let info = reader.info();
    let (width, height) = (info.width, info.height);
    if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen {
        return Err(TerrainError::NotGray16 { path: path.to_owned(), color_type: format!("{:?}", info.color_type).to_lowercase(), bit_depth: info.bit_depth as u8 });
    }
    if width < 2 || height < 2 {
        return Err(TerrainError::HeightmapTooSmall { path: path.to_owned(), width, height });
    }
    let size = reader.output_buffer_size().ok_or_else(|| TerrainError::Io { path: path.to_owned(), source: std::io::Error::other("image too large") })?;
    let mut buffer = vec![0; size];
    let frame = reader.next_frame(&mut buffer).map_err(png_error)?;
    let (rows, cols) = (height as usize, width as usize);
    let scale_v = f64::from(max_height_m) / 65535.0;
    let mut heights = Vec::with_capacity(rows * cols);
    for row in buffer.chunks_exact(frame.line_size).take(rows) {
        // 16-bit PNG samples are big-endian.
        heights.extend(row[..2 * cols].chunks_exact(2).map(|s| (f64::from(u16::from_be_bytes([s[0], s[1]])) * scale_v) as f32));
    }
    let size_z = size_m * (rows as f32 - 1.0) / (cols as f32 - 1.0);
    Ok(recentre(TerrainGeometry::HeightField { heights, rows, cols, scale: Vector::new(size_m, 1.0, size_z) }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall_spec(fillet_radius_m: f32, segments: u32) -> TerrainSpec {
        TerrainSpec::Wall { wall_distance_m: 0.5, wall_height_m: 1.5, width_m: 2.0, fillet_radius_m, segments }
    }

    #[test]
    fn the_unrolled_wall_keeps_the_floors_x_and_climbs_by_arc_length() {
        let sharp = UnrolledProfile::of(&wall_spec(0.0, 0)).unwrap();
        // Floor: u = x, normal up.
        let (p, n) = sharp.point(0.2, 0.3).unwrap();
        assert!((p - Vector::new(0.2, 0.0, 0.3)).length() < 1e-6 && (n - Vector::Y).length() < 1e-6, "{p:?} {n:?}");
        // 0.7 m along from x = 0 is 0.2 m up a wall 0.5 m ahead, facing the robot (−x).
        let (p, n) = sharp.point(0.7, -0.1).unwrap();
        assert!((p - Vector::new(0.5, 0.2, -0.1)).length() < 1e-6, "{p:?}");
        assert!((n - Vector::NEG_X).length() < 1e-6, "{n:?}");
        assert!((sharp.along(0.7).unwrap() - Vector::Y).length() < 1e-6);
        // Off the sheet: beyond its width, above the wall's top, before the floor's start.
        assert!(sharp.point(0.2, 1.01).is_none());
        assert!(sharp.point(0.5 + 1.5 + 0.01, 0.0).is_none());
        assert!(sharp.point(-1.01, 0.0).is_none());
        assert!(sharp.point(f32::NAN, 0.0).is_none());
        assert!(UnrolledProfile::of(&TerrainSpec::Flat { size_m: 1.0 }).is_none());
        // Laid flat again: a robot's centre 60 mm off the wall, 0.2 m up it, is at u = 0.7.
        let [u, z] = sharp.unroll(Vector::new(0.44, 0.2, 0.1));
        assert!((u - 0.7).abs() < 1e-6 && z == 0.1, "{u} {z}");
        assert!((sharp.unroll(Vector::new(-0.3, 0.06, 0.0))[0] + 0.3).abs() < 1e-6);
    }

    #[test]
    fn the_unrolled_fillet_lies_on_the_mesh_facets() {
        let spec = wall_spec(0.15, 24);
        let sheet = UnrolledProfile::of(&spec).unwrap();
        // The floor ends at x = 0.35; the 24 chords of the quarter circle are a little shorter
        // than its arc (π/2 · 0.15 = 0.2356 m).
        let chords = 24.0 * 2.0 * 0.15 * (std::f32::consts::FRAC_PI_4 / 24.0).sin();
        let (top, _) = sheet.point(0.35 + chords, 0.0).unwrap();
        assert!((top - Vector::new(0.5, 0.15, 0.0)).length() < 1e-5, "{top:?}");
        let (_, n) = sheet.point(0.35 + chords + 1e-3, 0.0).unwrap();
        assert!((n - Vector::NEG_X).length() < 1e-5, "{n:?}");
        // Halfway round the fillet the normal points about 45° between up and −x (within a
        // facet's 3.75°), toward the centre of the quarter circle (0.35, 0.15).
        let (mid, n) = sheet.point(0.35 + chords / 2.0, 0.0).unwrap();
        assert!(n.angle_between(Vector::new(-1.0, 1.0, 0.0)).to_degrees() <= 3.76, "{n:?}");
        assert!(((mid - Vector::new(0.35, 0.15, 0.0)).length() - 0.15).abs() < 1e-3, "{mid:?}");
        // Every point is on the generated mesh: a ray from the fillet's centre hits it there.
        let geometry = generate(&spec, 1, Path::new(".")).unwrap();
        let TerrainGeometry::TriMesh { vertices, indices } = geometry else { panic!("a wall is a trimesh") };
        let mesh = TriMesh::new(vertices, indices).unwrap();
        for k in 0..=40 {
            let u = 0.3 + 0.3 * k as f32 / 40.0;
            let (p, n) = sheet.point(u, 0.2).unwrap();
            let from = p + n * 0.05;
            let ray = rapier3d::parry::query::Ray::new(from, -n);
            let toi = rapier3d::parry::query::RayCast::cast_local_ray(&mesh, &ray, 1.0, false).unwrap();
            assert!((toi - 0.05).abs() < 1e-4, "u = {u}: the mesh is {toi} m away along the normal, not 0.05");
        }
    }
}
