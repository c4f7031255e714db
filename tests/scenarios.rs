//! Every shipped scenario loads and builds its world; a bad one names the file, line and key.

use std::path::Path;
use std::time::Duration;

use climbsim::robot::RobotDescription;
use climbsim::scenario::Scenario;
use climbsim::sim::Lockstep;

#[test]
fn every_shipped_scenario_builds_and_the_robot_rests_on_its_terrain() {
    let robot = RobotDescription::load(&RobotDescription::default_path()).expect("robot");
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).expect("scenarios dir") {
        let path = entry.expect("entry").path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let scenario = Scenario::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let mut sim = Lockstep::new(&robot, scenario.world_config().unwrap_or_else(|e| panic!("{e}"))).expect("world");
        sim.run(Duration::from_millis(500));
        // Resting: every magnet finds the surface within a millimetre of the tread.
        for sample in sim.world().adhesion() {
            assert!(sample.contact.is_some() && sample.gap_m < 0.001, "{}: {sample:?}", path.display());
        }
        count += 1;
    }
    assert!(count >= 5, "found {count} scenarios");
}

#[test]
fn bad_scenario_names_file_line_and_key() {
    let dir = std::env::temp_dir().join(format!("climbsim-scenario-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bad.toml");
    std::fs::write(&path, "[world]\nseed = 1\nduration_s = 5.0\n\n[terrain]\nkind = \"flat\"\nsize_m = 20.0\nroughness = 3\n").unwrap();
    let error = Scenario::load(&path).unwrap_err().to_string();
    // The terrain is an internally tagged enum, so the span serde reports is its table's line
    // ([terrain], line 5) rather than the key's own; the message names the key.
    assert!(error.contains(&format!("{}:5:", path.display())) && error.contains("roughness"), "{error}");
    std::fs::write(&path, "[world]\nseed = 1\nduration_s = 5.0\n\n[terrain]\nkind = \"perlin\"\nsize_m = 8.0\nresolution = 100\nmax_height_m = 0.04\nnoise_scale = 100.0\n").unwrap();
    let scenario = Scenario::load(&path).expect("parses");
    let error = scenario.world_config().unwrap_err().to_string();
    assert!(error.contains("bad.toml") && error.contains("100"), "{error}");
}

#[test]
fn the_solver_setting_is_read_from_the_world_table_and_a_zero_names_the_key() {
    let dir = std::env::temp_dir().join(format!("climbsim-solver-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("solver.toml");
    let base = "[world]\nseed = 1\nduration_s = 1.0\n";
    let terrain = "\n[terrain]\nkind = \"flat\"\nsize_m = 4.0\n";
    std::fs::write(&path, format!("{base}solver = {{ iterations = 5 }}\n{terrain}")).unwrap();
    let solver = Scenario::load(&path).expect("parses").world_config().expect("world").solver;
    assert_eq!((solver.iterations.get(), solver.internal_iterations.get()), (5, climbsim::sim::SolverSettings::default().internal_iterations.get()));
    std::fs::write(&path, format!("{base}solver = {{ iterations = 0, internal_iterations = 2 }}\n{terrain}")).unwrap();
    let error = Scenario::load(&path).unwrap_err().to_string();
    assert!(error.contains(&format!("{}:4:", path.display())) && error.contains("nonzero"), "{error}");
    std::fs::write(&path, format!("{base}solver = {{ ticks_per_step = 1 }}\n{terrain}")).unwrap();
    let solver = Scenario::load(&path).expect("parses").world_config().expect("world").solver;
    assert_eq!((solver.ticks_per_step.get(), solver.iterations), (1, climbsim::sim::SolverSettings::default().iterations));
    // Beyond what the solver-fidelity table vouches for: refused by key, with its range.
    std::fs::write(&path, format!("{base}solver = {{ ticks_per_step = 3 }}\n{terrain}")).unwrap();
    let error = Scenario::load(&path).unwrap_err().to_string();
    assert!(error.contains("world.solver.ticks_per_step") && error.contains("[1, 2]"), "{error}");
    let _ = std::fs::remove_dir_all(&dir);
}
