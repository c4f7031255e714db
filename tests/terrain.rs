//! Terrain generators: determinism, shape, and what rapier's ray casts see on the colliders.

use std::path::{Path, PathBuf};

use climbsim::sim::terrain::{Axis, TerrainError, TerrainGeometry, TerrainSpec, generate};
use rapier3d::prelude::{PhysicsWorld, QueryFilter, Ray, RigidBodyBuilder, Vector};

fn gen_ok(spec: &TerrainSpec, seed: u64) -> TerrainGeometry {
    generate(spec, seed, Path::new(".")).unwrap_or_else(|e| panic!("{spec:?}: {e}"))
}

fn perlin(resolution: u32, noise_scale: f32) -> TerrainSpec {
    TerrainSpec::Perlin { size_m: 8.0, resolution, max_height_m: 0.3, noise_scale }
}

fn heights(g: &TerrainGeometry) -> (&[f32], usize, usize) {
    match g {
        TerrainGeometry::HeightField { heights, rows, cols, .. } => (heights, *rows, *cols),
        TerrainGeometry::TriMesh { .. } => panic!("expected a heightfield"),
    }
}

/// A world holding only the terrain, stepped once (ray casts find nothing before the first step).
fn world_with(g: &TerrainGeometry) -> PhysicsWorld {
    let mut world = PhysicsWorld::default();
    world.insert(RigidBodyBuilder::fixed(), g.collider());
    world.step();
    world
}

/// The point where a ray from `origin` along unit `dir` first hits the terrain.
fn hit(world: &PhysicsWorld, origin: Vector, dir: Vector) -> Vector {
    let ray = Ray::new(origin, dir);
    let (_, toi) = world.cast_ray(&ray, 100.0, true, QueryFilter::default()).unwrap_or_else(|| panic!("ray from {origin:?} along {dir:?} hit nothing"));
    ray.point_at(toi)
}

fn hit_down(world: &PhysicsWorld, x: f32, z: f32) -> f32 {
    hit(world, Vector::new(x, 10.0, z), Vector::new(0.0, -1.0, 0.0)).y
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("climbsim-terrain-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_png(path: &Path, width: u32, height: u32, color: png::ColorType, depth: png::BitDepth, data: &[u8]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut encoder = png::Encoder::new(file, width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(data).unwrap();
    writer.finish().unwrap();
}

#[test]
fn perlin_is_deterministic_per_seed_and_bounded() {
    let spec = perlin(64, 100.0);
    let a = gen_ok(&spec, 7);
    let b = gen_ok(&spec, 7);
    let c = gen_ok(&spec, 8);
    assert_eq!(a.digest(), b.digest());
    assert_eq!(a, b, "same seed, same heights");
    assert_ne!(a.digest(), c.digest());
    let (ha, rows, cols) = heights(&a);
    let (hc, ..) = heights(&c);
    assert_eq!((rows, cols), (65, 65), "resolution counts cells: 64 cells, 65 samples per side");
    let differing = ha.iter().zip(hc).filter(|(x, y)| (*x - *y).abs() > 1e-3).count();
    assert!(differing > ha.len() / 2, "another seed gives another terrain ({differing} of {} differ)", ha.len());
    // Seeds differing only in their high bits give different terrains too.
    assert_ne!(a.digest(), gen_ok(&spec, 7 | (1 << 40)).digest());

    for h in [ha, hc] {
        let (min, max) = h.iter().fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        assert!(min >= -0.3 && max <= 0.3, "heights within ±max_height: [{min}, {max}]");
        assert!(max - min <= 0.3 + 1e-6, "peak-to-peak at most max_height: {}", max - min);
        assert!(max - min > 0.05, "bumpy terrain actually has bumps: {}", max - min);
    }
    assert_eq!(a.height_at(0.0, 0.0), Some(0.0), "centre at height 0");
}

#[test]
fn perlin_noise_scale_100_is_rougher_than_1000() {
    let mean_abs_step = |g: &TerrainGeometry| {
        let (h, rows, cols) = heights(g);
        let mut sum = 0.0f64;
        let mut n = 0;
        for i in 0..rows {
            for j in 0..cols {
                if j + 1 < cols {
                    sum += f64::from((h[i * cols + j + 1] - h[i * cols + j]).abs());
                    n += 1;
                }
                if i + 1 < rows {
                    sum += f64::from((h[(i + 1) * cols + j] - h[i * cols + j]).abs());
                    n += 1;
                }
            }
        }
        sum / f64::from(n)
    };
    let rough = mean_abs_step(&gen_ok(&perlin(64, 100.0), 3));
    let smooth = mean_abs_step(&gen_ok(&perlin(64, 1000.0), 3));
    assert!(rough > 3.0 * smooth, "noise scale 100: {rough} m per cell, 1000: {smooth} m per cell");

    // The terrain at a point does not depend on resolution (it only samples it).
    let coarse = gen_ok(&perlin(16, 100.0), 3);
    let fine = gen_ok(&perlin(64, 100.0), 3);
    let (x, z) = (1.5, -2.5); // a vertex of both grids (cells 0.5 m and 0.125 m)
    assert!((coarse.height_at(x, z).unwrap() - fine.height_at(x, z).unwrap()).abs() < 1e-6);
}

#[test]
fn slope_heights_and_ray_casts_follow_the_plane() {
    let (size, sx, sz) = (4.0f32, 20.0f32, -10.0f32);
    let g = gen_ok(&TerrainSpec::Slope { size_m: size, resolution: 16, slope_x_deg: sx, slope_z_deg: sz }, 0);
    let plane = |x: f32, z: f32| sx.to_radians().tan() * x + sz.to_radians().tan() * z;
    let world = world_with(&g);
    // Off-grid points (grid spacing 0.25 m), away from vertices and diagonals.
    for (x, z) in [(0.0371, 0.0213), (1.313, -0.871), (-1.777, 1.234), (0.61, 1.9), (-1.9, -1.93)] {
        let h = g.height_at(x, z).unwrap();
        assert!((h - plane(x, z)).abs() < 1e-4 * size, "height_at({x}, {z}) = {h}, plane {}", plane(x, z));
        let y = hit_down(&world, x, z);
        assert!((y - plane(x, z)).abs() < 1e-4 * size, "ray at ({x}, {z}) hit {y}, plane {}", plane(x, z));
    }
    assert_eq!(g.height_at(2.01, 0.0), None, "outside the terrain");
    assert_eq!(g.height_at(0.0, -2.01), None, "outside the terrain");
}

#[test]
fn height_at_matches_the_collider_on_bumpy_terrain() {
    // Interpolation on parry's own triangles: ray hits agree with height_at inside cells.
    let g = gen_ok(&perlin(32, 100.0), 11);
    let world = world_with(&g);
    for (x, z) in [(0.0377, 0.0911), (1.21, -2.93), (-3.07, 0.55), (2.44, 3.11), (-0.93, -1.61)] {
        let (expected, y) = (g.height_at(x, z).unwrap(), hit_down(&world, x, z));
        assert!((expected - y).abs() < 1e-4, "({x}, {z}): height_at {expected}, ray {y}");
    }
}

#[test]
fn height_at_uses_the_colliders_triangles_and_layout() {
    // Strongly twisted cells (a flat interpolation would differ from either diagonal split) on a
    // non-square grid, so a wrong diagonal or a transposed layout shows up at once.
    let (rows, cols) = (3usize, 4usize);
    let heights: Vec<f32> = (0..rows * cols).map(|k| if (k / cols + k % cols) % 2 == 0 { 0.0 } else { 0.5 } + 0.1 * k as f32).collect();
    let g = TerrainGeometry::HeightField { heights: heights.clone(), rows, cols, scale: Vector::new(3.0, 1.0, 2.0) };
    // Row i along z, column j along x: sample (i, j) sits at x = −1.5 + j, z = −1 + i.
    for (i, j) in [(1, 3), (2, 1), (0, 2)] {
        let h = g.height_at(-1.5 + j as f32, -1.0 + i as f32).unwrap();
        assert!((h - heights[i * cols + j]).abs() < 1e-6, "sample ({i}, {j}): {h} vs {}", heights[i * cols + j]);
    }
    let world = world_with(&g);
    let mut state = 12345u32;
    let mut next = || {
        state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        (state >> 8) as f32 / (1u32 << 24) as f32
    };
    for _ in 0..200 {
        let (x, z) = (-1.49 + 2.98 * next(), -0.99 + 1.98 * next());
        let (expected, y) = (g.height_at(x, z).unwrap(), hit_down(&world, x, z));
        assert!((expected - y).abs() < 1e-5, "({x}, {z}): height_at {expected}, ray {y}");
    }
}

#[test]
fn flat_is_flat() {
    let g = gen_ok(&TerrainSpec::Flat { size_m: 10.0 }, 0);
    let world = world_with(&g);
    for (x, z) in [(0.013, 0.021), (3.3, -4.1), (-4.9, 2.2)] {
        assert_eq!(g.height_at(x, z), Some(0.0));
        assert!(hit_down(&world, x, z).abs() < 1e-5);
    }
}

#[test]
fn pipe_vertices_on_radius_and_rays_hit_the_cylinder() {
    let (r, len, segments) = (0.5f32, 3.0f32, 64u32);
    // Inscribed polygon: the surface is at most the sagitta inside the true circle.
    let sagitta = r * (1.0 - (std::f32::consts::PI / segments as f32).cos());
    for axis in [Axis::X, Axis::Z] {
        let g = gen_ok(&TerrainSpec::Pipe { radius_m: r, length_m: len, axis, segments }, 0);
        assert_eq!(g.height_at(0.0, 0.0), None, "trimeshes have no height_at");
        let TerrainGeometry::TriMesh { vertices, .. } = &g else { panic!("pipe is a trimesh") };
        // (along, across): coordinates along and across the pipe axis.
        let split = |v: Vector| match axis {
            Axis::X => (v.x, v.z),
            Axis::Z => (v.z, v.x),
        };
        let mut on_radius = 0;
        for v in vertices {
            let (along, across) = split(*v);
            let d = (across.powi(2) + (v.y + r).powi(2)).sqrt();
            let end_cap_centre = d < 1e-6;
            assert!(end_cap_centre || (d - r).abs() < 1e-5, "vertex {v:?} at {d} from the axis");
            on_radius += usize::from(!end_cap_centre);
            assert!((along.abs() - len / 2.0).abs() < 1e-5, "vertex {v:?} not on an end ring");
        }
        assert_eq!(on_radius, 2 * segments as usize, "two rings of `segments` vertices");
        let world = world_with(&g);
        let point = |along: f32, across: f32| match axis {
            Axis::X => (along, across),
            Axis::Z => (across, along),
        };
        // At the top (just beside the top edge line, which a ray can slip through).
        let (x, z) = point(0.137, 1e-4);
        let top = hit_down(&world, x, z);
        assert!(top.abs() < 1e-5 && top <= 1e-6, "top of the pipe at 0, hit {top}");
        for offset in [0.1f32, -0.23, 0.37, 0.45] {
            let (x, z) = point(-0.61, offset);
            let y = hit_down(&world, x, z);
            let circle = (r * r - offset * offset).sqrt() - r;
            // Inscribed polygon: the hit is at most on the circle, and no deeper than the sagitta
            // measured radially (vertically that is sagitta / cos of the surface tilt).
            let d = (offset * offset + (y + r).powi(2)).sqrt();
            assert!(y <= circle + 1e-5 && d >= r - sagitta - 1e-5, "across {offset}: hit {y}, circle {circle}, {d} from the axis");
        }
        // Beyond the radius the ray misses the pipe.
        let (x, z) = point(0.3, r + 0.01);
        let ray = Ray::new(Vector::new(x, 10.0, z), Vector::new(0.0, -1.0, 0.0));
        assert!(world.cast_ray(&ray, 100.0, true, QueryFilter::default()).is_none());
    }
}

#[test]
fn wall_face_at_wall_distance_and_floor_at_zero() {
    let (d, h, w, fillet) = (1.2f32, 1.5f32, 2.0f32, 0.3f32);
    let spec = TerrainSpec::Wall { wall_distance_m: d, wall_height_m: h, width_m: w, fillet_radius_m: fillet, segments: 12 };
    let g = gen_ok(&spec, 0);
    let world = world_with(&g);
    for z in [0.123f32, -0.77] {
        let p = hit(&world, Vector::new(0.0, h / 2.0, z), Vector::new(1.0, 0.0, 0.0));
        assert!((p.x - d).abs() < 1e-5, "wall face at x = {d}, hit {p:?}");
    }
    for (x, z) in [(0.013f32, 0.021f32), (-0.9, 0.61), (d - fillet - 0.05, -0.5)] {
        let y = hit_down(&world, x, z);
        assert!(y.abs() < 1e-5, "floor at 0 at ({x}, {z}), hit {y}");
    }
    // On the fillet the surface rises: between floor and wall, below the circle's chord error.
    let x = d - fillet / 2.0;
    let y = hit_down(&world, x, 0.31);
    let circle = fillet - (fillet * fillet - (x - (d - fillet)).powi(2)).sqrt();
    assert!(y > 0.01 && (y - circle).abs() < 2e-3, "fillet at x = {x}: hit {y}, circle {circle}");
    // A sharp corner (fillet 0) works too.
    let sharp = TerrainSpec::Wall { wall_distance_m: d, wall_height_m: h, width_m: w, fillet_radius_m: 0.0, segments: 0 };
    let world = world_with(&gen_ok(&sharp, 0));
    let p = hit(&world, Vector::new(0.0, 0.05, 0.2), Vector::new(1.0, 0.0, 0.0));
    assert!((p.x - d).abs() < 1e-5, "sharp corner: hit {p:?}");
}

#[test]
fn heightmap_from_16_bit_png() {
    let dir = temp_dir("png");
    // 5 wide (x) × 3 high (z); value = 1000·column + 20000·row.
    let (width, height) = (5u32, 3u32);
    let value = |row: u32, col: u32| (1000 * col + 20000 * row) as u16;
    let data: Vec<u8> = (0..height).flat_map(|r| (0..width).flat_map(move |c| value(r, c).to_be_bytes())).collect();
    write_png(&dir.join("map.png"), width, height, png::ColorType::Grayscale, png::BitDepth::Sixteen, &data);
    let (size, max) = (4.0f32, 2.0f32);
    let spec = TerrainSpec::Heightmap { path: "map.png".into(), size_m: size, max_height_m: max };
    let g = generate(&spec, 0, &dir).unwrap();
    let TerrainGeometry::HeightField { heights, rows, cols, scale } = &g else { panic!("heightfield") };
    assert_eq!((*rows, *cols), (3, 5), "image rows along z, columns along x");
    assert_eq!(*scale, Vector::new(4.0, 1.0, 2.0), "square cells: z extent = size·(h−1)/(w−1)");
    let m = |v: u16| f32::from(v) / 65535.0 * max;
    let centre = m(value(1, 2));
    for r in 0..height {
        for c in 0..width {
            let expected = m(value(r, c)) - centre;
            let got = heights[(r * width + c) as usize];
            assert!((got - expected).abs() < 1e-6, "pixel ({r}, {c}): {got} vs {expected}");
        }
    }
    // Pixel (row 0, col 4) is at x = +2, z = −1: the image seen from above, +X right, +Z down.
    let corner = g.height_at(2.0, -1.0).unwrap();
    assert!((corner - (m(value(0, 4)) - centre)).abs() < 1e-6);
    assert_eq!(g.height_at(0.0, 0.0), Some(0.0));
    // Absolute paths are taken as they are.
    assert_eq!(generate(&TerrainSpec::Heightmap { path: dir.join("map.png"), size_m: size, max_height_m: max }, 0, Path::new("/nonexistent")).unwrap(), g);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_heightmaps_name_the_path() {
    let dir = temp_dir("bad-png");
    write_png(&dir.join("eight.png"), 2, 2, png::ColorType::Grayscale, png::BitDepth::Eight, &[0, 1, 2, 3]);
    std::fs::write(dir.join("junk.png"), b"not a png at all").unwrap();
    let load = |name: &str| generate(&TerrainSpec::Heightmap { path: name.into(), size_m: 1.0, max_height_m: 1.0 }, 0, &dir).unwrap_err();

    let e = load("eight.png");
    assert!(matches!(&e, TerrainError::NotGray16 { path, bit_depth: 8, .. } if *path == dir.join("eight.png")), "{e:?}");
    assert!(e.to_string().contains("eight.png") && e.to_string().contains("16-bit grayscale"), "{e}");

    let e = load("missing.png");
    assert!(matches!(&e, TerrainError::Io { path, source } if *path == dir.join("missing.png") && source.kind() == std::io::ErrorKind::NotFound), "{e:?}");
    assert!(e.to_string().contains(&dir.join("missing.png").display().to_string()), "{e}");

    let e = load("junk.png");
    assert!(matches!(&e, TerrainError::Png { path, .. } if *path == dir.join("junk.png")), "{e:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn invalid_specs_are_rejected() {
    let err = |spec: TerrainSpec| generate(&spec, 0, Path::new(".")).unwrap_err();
    let e = err(TerrainSpec::Perlin { size_m: 8.0, resolution: 100, max_height_m: 0.3, noise_scale: 100.0 });
    assert!(matches!(e, TerrainError::ResolutionNotPowerOfTwo { resolution: 100 }), "{e:?}");
    assert!(e.to_string().contains("100") && e.to_string().contains("power of two"), "{e}");
    let e = err(TerrainSpec::Slope { size_m: 8.0, resolution: 0, slope_x_deg: 1.0, slope_z_deg: 0.0 });
    assert!(matches!(e, TerrainError::ResolutionNotPowerOfTwo { resolution: 0 }), "{e:?}");
    let e = err(TerrainSpec::Slope { size_m: 8.0, resolution: 1 << 14, slope_x_deg: 1.0, slope_z_deg: 0.0 });
    assert!(matches!(e, TerrainError::ResolutionTooLarge { .. }), "{e:?}");
    let e = err(TerrainSpec::Flat { size_m: 0.0 });
    assert!(matches!(e, TerrainError::NotPositive { field: "size_m", .. }), "{e:?}");
    let e = err(TerrainSpec::Perlin { size_m: 8.0, resolution: 64, max_height_m: -1.0, noise_scale: 100.0 });
    assert!(matches!(e, TerrainError::NotPositive { field: "max_height_m", .. }), "{e:?}");
    let e = err(TerrainSpec::Perlin { size_m: f32::NAN, resolution: 64, max_height_m: 1.0, noise_scale: 100.0 });
    assert!(matches!(e, TerrainError::NotPositive { field: "size_m", .. }), "{e:?}");
    let e = err(TerrainSpec::Slope { size_m: 8.0, resolution: 8, slope_x_deg: 90.0, slope_z_deg: 0.0 });
    assert!(matches!(e, TerrainError::Invalid { field: "slope_x_deg", .. }), "{e:?}");
    let e = err(TerrainSpec::Pipe { radius_m: 0.5, length_m: 2.0, axis: Axis::X, segments: 2 });
    assert!(matches!(e, TerrainError::Invalid { field: "segments", .. }), "{e:?}");
    let e = err(TerrainSpec::Wall { wall_distance_m: 0.5, wall_height_m: 1.0, width_m: 1.0, fillet_radius_m: 0.6, segments: 8 });
    assert!(matches!(e, TerrainError::Invalid { field: "fillet_radius_m", .. }), "{e:?}");
}

#[test]
fn specs_parse_from_scenario_toml() {
    #[derive(serde::Deserialize)]
    struct Scenario {
        terrain: TerrainSpec,
    }
    let parse = |text: &str| toml::from_str::<Scenario>(text).map(|s| s.terrain);
    assert_eq!(
        parse("[terrain]\nkind = \"perlin\"\nsize_m = 8.0\nresolution = 256\nmax_height_m = 0.1\nnoise_scale = 100.0\n").unwrap(),
        TerrainSpec::Perlin { size_m: 8.0, resolution: 256, max_height_m: 0.1, noise_scale: 100.0 }
    );
    assert_eq!(
        parse("[terrain]\nkind = \"pipe\"\nradius_m = 0.5\nlength_m = 4.0\naxis = \"z\"\nsegments = 64\n").unwrap(),
        TerrainSpec::Pipe { radius_m: 0.5, length_m: 4.0, axis: Axis::Z, segments: 64 }
    );
    assert_eq!(
        parse("[terrain]\nkind = \"heightmap\"\npath = \"maps/a.png\"\nsize_m = 8.0\nmax_height_m = 0.2\n").unwrap(),
        TerrainSpec::Heightmap { path: "maps/a.png".into(), size_m: 8.0, max_height_m: 0.2 }
    );
    let e = parse("[terrain]\nkind = \"flat\"\nsize_m = 8.0\nsize = 3\n").unwrap_err();
    assert!(e.to_string().contains("size"), "unknown fields rejected: {e}");
    assert!(parse("[terrain]\nkind = \"lava\"\n").is_err());
}

/// Unit normals of a trimesh's triangles (right-hand rule on the index order) with centroids.
fn facets(g: &TerrainGeometry) -> Vec<(Vector, Vector)> {
    let TerrainGeometry::TriMesh { vertices, indices } = g else { panic!("trimesh expected") };
    indices
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            ((b - a).cross(c - a).normalize(), (a + b + c) / 3.0)
        })
        .collect()
}

#[test]
fn trimesh_triangles_face_the_robot() {
    // One-sided FIX_INTERNAL_EDGES drops contacts from behind a triangle: the winding matters.
    for axis in [Axis::X, Axis::Z] {
        let r = 0.4;
        let g = gen_ok(&TerrainSpec::Pipe { radius_m: r, length_m: 2.0, axis, segments: 16 }, 0);
        for (n, c) in facets(&g) {
            let (along, across) = match axis {
                Axis::X => (Vector::X, Vector::Z),
                Axis::Z => (Vector::Z, Vector::X),
            };
            let radial = Vector::new(0.0, c.y + r, 0.0) + across * c.dot(across);
            let outward = if radial.length() < 1e-4 * r || n.dot(along).abs() > 0.99 { along * c.dot(along).signum() } else { radial.normalize() };
            assert!(n.dot(outward) > 0.9, "pipe ({axis:?}) facet at {c:?} has normal {n:?}");
        }
    }
    let wall = TerrainSpec::Wall { wall_distance_m: 1.0, wall_height_m: 1.0, width_m: 1.0, fillet_radius_m: 0.2, segments: 6 };
    for (n, c) in facets(&gen_ok(&wall, 0)) {
        // Up on the floor, −X on the face, towards the fillet's centre (0.8, 0.2) on the fillet.
        let expected = if c.x < 0.8 {
            Vector::Y
        } else if c.y > 0.2 {
            -Vector::X
        } else {
            (Vector::new(0.8, 0.2, c.z) - c).normalize()
        };
        assert!(n.dot(expected) > 0.9, "wall facet at {c:?} has normal {n:?}, expected {expected:?}");
    }
}

#[test]
fn a_ball_rests_on_each_terrain() {
    // Physical check of the collider flags and winding: a ball dropped on the terrain settles on
    // its surface instead of falling through (contacts from behind a one-sided triangle are dropped).
    let ball = 0.05;
    let cases = [
        (TerrainSpec::Flat { size_m: 4.0 }, Vector::new(0.3, 0.2, 0.2)),
        (perlin(32, 100.0), Vector::new(0.31, 0.5, -0.27)),
        (TerrainSpec::Slope { size_m: 4.0, resolution: 8, slope_x_deg: 5.0, slope_z_deg: 0.0 }, Vector::new(0.31, 0.5, -0.27)),
        (TerrainSpec::Pipe { radius_m: 0.5, length_m: 2.0, axis: Axis::Z, segments: 64 }, Vector::new(0.01, 0.2, 0.13)),
        (TerrainSpec::Pipe { radius_m: 0.5, length_m: 2.0, axis: Axis::X, segments: 64 }, Vector::new(0.13, 0.2, 0.01)),
        (TerrainSpec::Wall { wall_distance_m: 1.0, wall_height_m: 1.0, width_m: 1.0, fillet_radius_m: 0.2, segments: 8 }, Vector::new(0.3, 0.2, 0.1)),
    ];
    for (spec, start) in cases {
        let g = gen_ok(&spec, 5);
        let mut world = PhysicsWorld::default();
        world.insert(RigidBodyBuilder::fixed(), g.collider());
        let (body, _) = world.insert(RigidBodyBuilder::dynamic().translation(start).linear_damping(5.0).angular_damping(5.0), rapier3d::prelude::ColliderBuilder::ball(ball));
        for _ in 0..60 {
            world.step();
        }
        let p = world.bodies[body].translation();
        let ray = Ray::new(p, Vector::new(0.0, -1.0, 0.0));
        let below = world.cast_ray(&ray, 10.0, true, QueryFilter::default().exclude_rigid_body(body));
        let gap = below.map(|(_, toi)| toi);
        // Vertical centre-to-surface distance: the radius on flat ground, radius / cos(tilt) on a tilt.
        assert!(gap.is_some_and(|d| d > ball - 0.005 && d < ball / 45f32.to_radians().cos()), "{spec:?}: ball at {p:?}, surface {gap:?} below");
    }
}

#[test]
fn bump_is_where_it_is_asked_for() {
    let spec = TerrainSpec::Bump { size_m: 6.0, resolution: 256, height_m: 0.03, radius_m: 0.2, x_m: 0.5, z_m: 0.13 };
    let bump = generate(&spec, 1, Path::new(".")).unwrap();
    let peak = bump.height_at(0.5, 0.13).unwrap();
    assert!((peak - 0.03).abs() < 1e-3, "peak {peak}");
    for (x, z) in [(0.16, 0.13), (0.5, -0.13), (-1.0, 2.0), (0.5, 0.4)] {
        assert!(bump.height_at(x, z).unwrap().abs() < 1e-6, "flat at ({x}, {z}): {}", bump.height_at(x, z).unwrap());
    }
}
