//! `path.png` checked by content: decoded, its weld-line and robot pixels found by colour, and
//! the robot's track where the run's start and the controller put it.

use std::path::Path;
use std::process::Command;

mod support;

/// The plot's colours (src/report/path.rs: the palette's first and eighth).
const TRACK_RGB: [u8; 3] = [31, 119, 180];
const LINE_RGB: [u8; 3] = [127, 127, 127];
/// Rows above this hold the caption and the legend (whose samples have the same colours).
const BELOW_LEGEND_ROW: usize = 160;

/// `climbsim run SCENARIO` for `seconds` into `out`; path.png's pixels, width and channels.
fn path_picture(scenario: &str, seconds: u32, out: &Path) -> (Vec<u8>, usize, usize) {
    let output = Command::new(env!("CARGO_BIN_EXE_climbsim"))
        .args(["run", scenario, "--set", &format!("world.duration_s={seconds}"), "--set", "expect={}", "--set", "capture.mcap=false", "--out", &out.display().to_string()])
        .current_dir(support::repo())
        .output()
        .expect("climbsim");
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(out.join("path.svg").exists());
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(out.join("path.png")).expect("path.png")));
    let mut reader = decoder.read_info().expect("PNG");
    let mut pixels = vec![0; reader.output_buffer_size().expect("size")];
    let info = reader.next_frame(&mut pixels).expect("frame");
    let (width, channels) = (info.width as usize, info.color_type.samples());
    (pixels, width, channels)
}

/// The distinct colours of the terrain's shading (pale sand to khaki: red over green over
/// blue, src/report/path.rs) below the caption, and how many pixels have them.
fn shading(pixels: &[u8], width: usize, channels: usize) -> (usize, usize) {
    let mut colours = std::collections::BTreeSet::new();
    let mut count = 0;
    for i in BELOW_LEGEND_ROW * width..pixels.len() / channels {
        let [r, g, b] = [pixels[i * channels], pixels[i * channels + 1], pixels[i * channels + 2]];
        if r >= 190 && r >= g && g > b && r - b >= 10 {
            colours.insert([r, g, b]);
            count += 1;
        }
    }
    (colours.len(), count)
}

#[test]
fn the_terrain_is_shaded_by_height_and_flat_ground_is_not() {
    // A pipe: the ground falls away either side of its top line.
    let (pixels, width, channels) = path_picture("scenarios/pipe-line.toml", 3, &support::scratch_dir("path-pipe").join("run"));
    let (colours, count) = shading(&pixels, width, channels);
    assert!(colours >= 10 && count > 100_000, "{colours} shades over {count} px");
    let (pixels, width, channels) = path_picture("scenarios/flat-line.toml", 3, &support::scratch_dir("path-flat").join("run"));
    assert_eq!(shading(&pixels, width, channels), (0, 0), "flat ground is not shaded");
}

#[test]
fn the_track_starts_50_mm_left_of_the_line_and_closes_in_on_it() {
    let (pixels, width, channels) = path_picture("scenarios/flat-line.toml", 25, &support::scratch_dir("path").join("run"));
    let coloured = |rgb: [u8; 3]| -> Vec<(usize, usize)> {
        (BELOW_LEGEND_ROW * width..pixels.len() / channels).filter(|&i| pixels[i * channels..i * channels + 3] == rgb).map(|i| (i % width, i / width)).collect()
    };
    let (line, track) = (coloured(LINE_RGB), coloured(TRACK_RGB));
    assert!(line.len() > 500 && track.len() > 50, "line {} px, track {} px", line.len(), track.len());

    // The line runs along x at z = 0 from x = -0.5 to 3.0 m: one row, and its length the scale.
    let mut rows: Vec<usize> = line.iter().map(|&(_, row)| row).collect();
    rows.sort_unstable();
    let line_row = rows[rows.len() / 2] as f64;
    let (first_col, last_col) = (line.iter().map(|p| p.0).min().expect("line"), line.iter().map(|p| p.0).max().expect("line"));
    let px_per_m = (last_col - first_col) as f64 / 3.5;

    // The robot starts 50 mm left of the line (up in the picture), and at the end of 25 s it is
    // closer. Column by column, the track's highest pixel is its centre to within a pixel.
    let row_at = |col: usize| track.iter().filter(|p| p.0 == col).map(|p| p.1).min();
    let track_first = track.iter().map(|p| p.0).min().expect("track");
    let track_last = track.iter().map(|p| p.0).max().expect("track");
    // Just right of the start marker (a dot of radius 6 px).
    let start_col = (track_first..=track_last).find(|&c| c > track_first + 2 && row_at(c).is_some()).expect("track after the marker");
    let start_offset_m = (line_row - row_at(start_col).expect("row") as f64) / px_per_m;
    assert!((start_offset_m - 0.05).abs() < 0.006, "the track starts {start_offset_m:.4} m left of the line, not 0.05");
    let end_offset_m = (line_row - row_at(track_last - 8).expect("row") as f64) / px_per_m;
    assert!(end_offset_m < start_offset_m / 2.0, "after 25 s the robot is {end_offset_m:.4} m from the line");
    assert!(track.iter().all(|&(_, row)| row as f64 <= line_row + 2.0), "the robot never crossed to the right of the line");
}
