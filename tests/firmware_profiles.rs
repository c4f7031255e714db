//! Every firmware profile against the e-manual's facts written beside it
//! (`firmware-profiles/e-manual/MODEL.table.psv` and `MODEL.facts.toml`), and every profile's servo
//! doing what its page says on the bench.

use std::collections::BTreeMap;
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use climbsim::device::profile::{Access, Area, Bound};
use climbsim::device::{Addressing, BenchLoad, DeviceError, FirmwareProfile, Request, Servo, ShaftLoad};

fn profiles_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profiles")
}

/// Every profile file, with the e-manual model its facts are filed under (`xm540-w270-r.toml`:
/// `xm540-w270`, the page covers the -R and -T alike).
fn profiles() -> Vec<(PathBuf, String)> {
    let mut found: Vec<_> = std::fs::read_dir(profiles_dir())
        .expect("firmware-profiles/ reads")
        .map(|entry| entry.expect("an entry").path())
        .filter(|path| path.extension().is_some_and(|ext| ext == "toml"))
        .map(|path| {
            let stem = path.file_stem().and_then(|s| s.to_str()).expect("a UTF-8 name").to_owned();
            let model = stem.strip_suffix("-r").or_else(|| stem.strip_suffix("-t")).unwrap_or(&stem).to_owned();
            (path, model)
        })
        .collect();
    found.sort();
    assert!(found.len() >= 11, "the profiles: {found:?}");
    found
}

struct Row {
    line: usize,
    address: u16,
    size: u16,
    name: String,
    access: String,
    default: String,
    range: String,
    unit: String,
}

fn manual_rows(model: &str) -> Vec<Row> {
    let path = profiles_dir().join("e-manual").join(format!("{model}.table.psv"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e} (every profile has its page's table beside it)", path.display()));
    text.lines()
        .enumerate()
        .filter(|(_, line)| !line.trim().is_empty() && !line.starts_with('#') && !line.starts_with("address|"))
        .map(|(n, line)| {
            let cells: Vec<&str> = line.split('|').map(str::trim).collect();
            assert_eq!(cells.len(), 7, "{}:{}: seven cells", path.display(), n + 1);
            Row {
                line: n + 1,
                address: cells[0].parse().expect("an address"),
                size: cells[1].parse().expect("a size"),
                name: cells[2].to_owned(),
                access: cells[3].to_owned(),
                default: cells[4].to_owned(),
                range: cells[5].to_owned(),
                unit: cells[6].to_owned(),
            }
        })
        .collect()
}

fn facts(model: &str) -> toml::Table {
    let path = profiles_dir().join("e-manual").join(format!("{model}.facts.toml"));
    toml::from_str(&std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).expect("facts parse")
}

fn text<'a>(table: &'a toml::Table, section: &str, key: &str) -> &'a str {
    table[section][key].as_str().unwrap_or_else(|| panic!("[{section}] {key} is a string"))
}

/// A cell with two readings (velocity- and time-based profile) is checked on the first.
fn first(cell: &str) -> &str {
    cell.split(" / ").next().unwrap_or(cell).trim()
}

/// The departures from the page the facts file names, as "key.field" with the value the profile
/// takes instead; each names why.
fn deviations(facts: &toml::Table) -> BTreeMap<String, toml::Value> {
    let Some(section) = facts.get("deviations").and_then(|d| d.as_table()) else { return BTreeMap::new() };
    let mut found = BTreeMap::new();
    for (key, fields) in section {
        let fields = fields.as_table().unwrap_or_else(|| panic!("[deviations.{key}] is a table"));
        assert!(fields.get("why").and_then(|w| w.as_str()).is_some_and(|w| !w.is_empty()), "[deviations.{key}] says why");
        for (field, value) in fields.iter().filter(|(field, _)| *field != "why") {
            found.insert(format!("{key}.{field}"), value.clone());
        }
    }
    found
}

fn bound_address(profile: &FirmwareProfile, bound: Option<Bound>) -> Option<(bool, u16)> {
    match bound {
        Some(Bound::Item { index, negate }) => Some((negate, profile.items[index].address())),
        _ => None,
    }
}

/// The reading of a specification cell ("1.5 [N.m] (at 12.0 [V], 1.4 [A]) / …") at `volts`:
/// the value and the current if the cell gives one.
fn at_voltage(cell: &str, volts: f64) -> (f64, Option<f64>) {
    for part in cell.split(" / ") {
        let number = |s: &str| s.trim().trim_start_matches('(').split(|c: char| !(c.is_ascii_digit() || c == '.')).next().and_then(|n| n.parse::<f64>().ok());
        let Some(value) = number(part) else { continue };
        let Some(at) = part.split("(at").nth(1) else { continue };
        let Some(v) = number(at) else { continue };
        if (v - volts).abs() < 1e-9 {
            let amps = at.split([',', 'V']).filter(|s| s.contains("[A]")).find_map(|s| number(s.trim_start_matches(']').trim()));
            return (value, amps);
        }
    }
    panic!("no reading at {volts} V in {cell:?}")
}

/// The mode an e-manual section names ("Current-based Position Control Mode", …).
fn mode_role(name: &str) -> &'static str {
    let name = name.to_lowercase();
    [("current-based", "current_based_position"), ("extended", "extended_position"), ("pwm", "pwm"), ("current", "current"), ("velocity", "velocity"), ("position", "position")]
        .into_iter()
        .find(|(word, _)| name.contains(word))
        .map(|(_, role)| role)
        .unwrap_or_else(|| panic!("no mode in {name:?}"))
}

/// A unit as profiles spell it, from the e-manual's (`[μsec]` is `us`).
fn unit_name(page: &str) -> &str {
    match page {
        "μsec" => "us",
        "°C" => "degC",
        "msec" => "ms",
        "rev/min²" | "rev/min2" => "rev/min^2",
        other => other,
    }
}

/// The indirect blocks the page's rows show: (address start, data start, entries), each from its
/// first listed Indirect Address to its last (the page elides the middle of a block).
fn page_indirect_blocks(rows: &[Row]) -> Vec<(u16, u16, u16)> {
    let numbered = |prefix: &str| -> BTreeMap<u16, u16> { rows.iter().filter_map(|r| r.name.strip_prefix(prefix).and_then(|n| n.parse().ok()).map(|n| (n, r.address))).collect() };
    let (addresses, data) = (numbered("Indirect Address "), numbered("Indirect Data "));
    let mut blocks: Vec<(u16, u16, u16)> = Vec::new();
    let mut first: Option<u16> = None;
    for (&n, &address) in &addresses {
        match first {
            Some(start) if address == addresses[&start] + 2 * (n - start) => {}
            _ => first = Some(n),
        }
        let start = first.expect("set above");
        let block = (addresses[&start], data[&start], n - start + 1);
        match blocks.last_mut() {
            Some(last) if last.0 == block.0 => *last = block,
            _ => blocks.push(block),
        }
    }
    blocks
}

#[test]
fn every_profile_matches_its_e_manual_page_item_by_item() {
    let mut checked = BTreeMap::new();
    for (path, model) in profiles() {
        let profile = FirmwareProfile::load(&path).unwrap_or_else(|e| panic!("{e}"));
        let facts = facts(&model);
        let allowed = deviations(&facts);
        let rows = manual_rows(&model);
        let psv = format!("firmware-profiles/e-manual/{model}.table.psv");
        let mut problems = Vec::new();
        for row in &rows {
            let at = format!("{psv}:{} ({} at {})", row.line, row.name, row.address);
            let Some(index) = profile.item_index_at(row.address).filter(|&i| profile.items[i].address() == row.address) else {
                problems.push(format!("{at}: no item at this address in {}", path.display()));
                continue;
            };
            let item = &profile.items[index];
            let key = &item.spec.key;
            let instead = |field: &str| allowed.get(&format!("{key}.{field}"));
            if item.spec.name != row.name && !(row.name == "Protocol Version" && key == "protocol_type") {
                problems.push(format!("{at}: named `{}`", item.spec.name));
            }
            if item.spec.size != row.size {
                problems.push(format!("{at}: size {} against the page's {}", item.spec.size, row.size));
            }
            let access = if row.access == "R" { Access::R } else { Access::RW };
            if item.spec.access != access {
                problems.push(format!("{at}: access {:?} against the page's {}", item.spec.access, row.access));
            }
            let area = if row.address < 64 { Area::Eeprom } else { Area::Ram };
            if item.spec.area != area {
                problems.push(format!("{at}: area {:?}", item.spec.area));
            }
            let value = |field: &str| instead(field).map(|v| v.as_integer().unwrap_or_else(|| panic!("{at}: [deviations.{key}] {field} is an integer")));
            if let Ok(page_default) = row.default.parse::<i64>() {
                let expected = value("default").unwrap_or(page_default);
                if item.spec.default != Some(expected) {
                    problems.push(format!("{at}: default {:?} against {expected} (the page's {page_default})", item.spec.default));
                }
            }
            let range = first(&row.range);
            // The constant bounds the page gives: none ("-"), "low ~ high", or "3" (0 to 3,
            // Startup Configuration's bits); bounds named by items are checked on their own.
            let numbers = |low: &str, high: &str| low.trim().parse::<i64>().ok().zip(high.trim().parse::<i64>().ok());
            let page_bounds: Option<(Option<i64>, Option<i64>)> = if range == "-" {
                Some((None, None))
            } else if let Some((low, high)) = range.split_once('~') {
                match numbers(low, high) {
                    Some((low, high)) => Some((Some(low), Some(high))),
                    None => {
                        // "-PWM Limit(36) ~ PWM Limit(36)": bounds named by the items' addresses.
                        let reference = |side: &str| {
                            let side = side.trim();
                            let address = side.rsplit_once('(').and_then(|(_, a)| a.trim_end_matches(')').parse::<u16>().ok()).expect("an address in parentheses");
                            (side.starts_with('-'), address)
                        };
                        if bound_address(&profile, item.min) != Some(reference(low)) || bound_address(&profile, item.max) != Some(reference(high)) {
                            problems.push(format!("{at}: bounds {:?}..{:?} against the page's {range}", item.spec.min_ref, item.spec.max_ref));
                        }
                        None
                    }
                }
            } else if let Ok(high) = range.parse::<i64>() {
                Some((Some(0), Some(high)))
            } else {
                problems.push(format!("{at}: the range {range:?} is not one this test reads"));
                None
            };
            if let Some((page_min, page_max)) = page_bounds {
                let expected = (value("min").or(page_min), value("max").or(page_max));
                if (item.spec.min, item.spec.max) != expected || (page_min.is_none() && (item.spec.min_ref.is_some() || item.spec.max_ref.is_some())) {
                    problems.push(format!("{at}: bounds {:?}..{:?} against {:?}..{:?} (the page's {range})", item.spec.min, item.spec.max, expected.0, expected.1));
                }
            }
            // A value that may be negative is signed.
            let negative = range != "-" && (range.starts_with('-') || range.contains("~ -") || range.contains("~-"));
            if negative && !item.spec.signed {
                problems.push(format!("{at}: unsigned, but the page's range {range} goes below zero"));
            }
            let unit = first(&row.unit);
            if unit == "-" {
                // A gain's unit is its section's divisor; otherwise none, or the departure's.
                let divisor = facts.get("conversions").and_then(|c| c.get(key.as_str())).and_then(toml::Value::as_integer);
                let expected = match (divisor, instead("scale")) {
                    (_, Some(scale)) => (instead("unit").and_then(|u| u.as_str()), scale.as_float()),
                    (Some(divisor), None) => (None, Some(1.0 / divisor as f64)),
                    (None, None) => (None, None),
                };
                if (item.spec.unit.as_deref(), item.spec.scale) != expected {
                    problems.push(format!("{at}: unit {:?} × {:?} where the page gives none (expected {expected:?})", item.spec.unit, item.spec.scale));
                }
            } else {
                let (scale, name) = unit.split_once('[').unwrap_or_else(|| panic!("{at}: unit {unit:?}"));
                let scale: f64 = scale.trim().parse().unwrap_or_else(|_| panic!("{at}: unit {unit:?}"));
                let name = unit_name(name.trim_end_matches(']').trim());
                if item.spec.scale != Some(scale) || item.spec.unit.as_deref() != Some(name) {
                    problems.push(format!("{at}: unit {:?} × {:?} against the page's {unit}", item.spec.unit, item.spec.scale));
                }
            }
        }
        // What the profile has and the page does not write: only the indirect entries the page
        // elides inside a block it lists (from its first listed entry to its last).
        let blocks = page_indirect_blocks(&rows);
        for item in &profile.items {
            if rows.iter().any(|row| row.address == item.address()) {
                continue;
            }
            let elided = blocks.iter().any(|&(address_start, data_start, count)| {
                let address = (address_start..address_start + 2 * count).step_by(2).any(|a| a == item.address());
                let data = (data_start..data_start + count).any(|a| a == item.address());
                address || data
            });
            if !elided {
                problems.push(format!("{}: item `{}` at {} is not on the page ({psv})", path.display(), item.spec.key, item.address()));
            }
        }
        // The model's identity, baud rates and operating modes.
        let model_row = rows.iter().find(|r| r.address == 0).expect("Model Number row");
        if model_row.default.parse::<u16>().ok() != Some(profile.model.model_number) {
            problems.push(format!("{psv}: Model Number {} against [model] model_number {}", model_row.default, profile.model.model_number));
        }
        let bauds: Vec<(u8, u32)> = text(&facts, "sections", "baud_codes")
            .split(',')
            .map(|pair| {
                let (code, bps) = pair.trim().split_once(':').expect("code:bps");
                (code.parse().expect("a code"), bps.parse().expect("bps"))
            })
            .collect();
        let profile_bauds: Vec<(u8, u32)> = profile.baud_rates.iter().map(|b| (b.code, b.bps)).collect();
        if bauds != profile_bauds {
            problems.push(format!("{}: baud rates {profile_bauds:?} against the page's {bauds:?}", path.display()));
        }
        let mut modes: Vec<i64> = text(&facts, "sections", "operating_mode_values").split(',').map(|pair| pair.trim().split(':').next().and_then(|c| c.parse().ok()).expect("a mode")).collect();
        modes.sort_unstable();
        let operating_mode = &profile.items[profile.index("operating_mode")];
        if operating_mode.spec.values.as_ref() != Some(&modes) {
            problems.push(format!("{}: operating modes {:?} against the page's {modes:?}", path.display(), operating_mode.spec.values));
        }
        let page_modes: BTreeMap<&str, i64> = text(&facts, "sections", "operating_mode_values")
            .split(',')
            .map(|pair| {
                let (code, name) = pair.trim().split_once(':').expect("code:name");
                (mode_role(name), code.parse().expect("a mode"))
            })
            .collect();
        let named = &profile.operating_modes;
        let declared: BTreeMap<&str, i64> = [
            ("current", named.current),
            ("velocity", Some(named.velocity)),
            ("position", Some(named.position)),
            ("extended_position", Some(named.extended_position)),
            ("current_based_position", named.current_based_position),
            ("pwm", Some(named.pwm)),
        ]
        .into_iter()
        .filter_map(|(role, code)| code.map(|code| (role, i64::from(code))))
        .collect();
        if declared != page_modes {
            problems.push(format!("{}: [operating_modes] {declared:?} against the page's {page_modes:?}", path.display()));
        }
        let page_name = text(&facts, "model", "name");
        if profile.model.name != page_name {
            problems.push(format!("{}: [model] name {:?} against the facts' {page_name:?}", path.display(), profile.model.name));
        }
        // The motor's datasheet figures at the recommended voltage.
        let motor = &profile.motor;
        let recommended: f64 = text(&facts, "specification", "input_voltage")
            .split("Recommended")
            .nth(1)
            .and_then(|s| s.trim_start_matches([' ', ':']).split(' ').next())
            .and_then(|v| v.parse().ok())
            .expect("a recommended voltage");
        let (torque, amps) = at_voltage(text(&facts, "specification", "stall_torque"), recommended);
        let (speed, _) = at_voltage(text(&facts, "specification", "no_load_speed"), recommended);
        let gear: f64 = text(&facts, "specification", "gear_ratio").split(':').next().and_then(|g| g.trim().parse().ok()).expect("a gear ratio");
        let standby: f64 = text(&facts, "specification", "standby_current").split(' ').next().and_then(|s| s.parse().ok()).expect("a standby current");
        for (what, ours, page) in [
            ("rated_voltage_v", motor.rated_voltage_v, recommended),
            ("stall_torque_nm", motor.stall_torque_nm, torque),
            ("stall_current_a", motor.stall_current_a, amps.expect("a stall current")),
            ("no_load_speed_rpm", motor.no_load_speed_rpm, speed),
            ("gear_ratio", motor.gear_ratio, gear),
            ("standby_current_a", motor.standby_current_a, standby / 1000.0),
        ] {
            if (ours - page).abs() > 1e-9 {
                problems.push(format!("{}: [motor] {what} = {ours} against the page's {page}", path.display()));
            }
        }
        assert!(problems.is_empty(), "{} disagrees with its e-manual page:\n{}", path.display(), problems.join("\n"));
        checked.insert(profile.model.name.clone(), rows.len());
    }
    for model in ["XL330-M077", "XL330-M288", "XC330-T288", "XL430-W250", "XC430-W150", "XM430-W210", "XM430-W350", "XH430-W350", "XM540-W150", "XW540-T260", "XM540-W270-R"] {
        assert!(checked.keys().any(|name| name.starts_with(model)), "no profile for {model}: {checked:?}");
    }
}

fn write(servo: &mut Servo, address: u16, data: &[u8]) -> Result<Vec<u8>, DeviceError> {
    servo.handle(Duration::ZERO, Request::Write { address, data }, Addressing::default()).reply
}

fn run(servo: &mut Servo, load: &mut BenchLoad, seconds: f64) {
    let mut now = Duration::ZERO;
    for _ in 0..(seconds / servo.control_period().as_secs_f64()) as usize {
        now += servo.control_period();
        let drive = servo.drive();
        let state = load.step(&drive, servo.control_period().as_secs_f64());
        servo.sense(now, state);
    }
}

fn read(servo: &mut Servo, address: u16, length: u16) -> Vec<u8> {
    servo.handle(Duration::ZERO, Request::Read { address, length }, Addressing::default()).reply.expect("a read inside the table")
}

#[test]
fn every_profiles_servo_pings_with_its_model_and_runs_at_its_datasheet_speed() {
    for (path, _) in profiles() {
        let profile = Arc::new(FirmwareProfile::load(&path).expect("loads"));
        let mut servo = Servo::new(Arc::clone(&profile), 1, 1, profile.motor.rated_voltage_v);
        let ping = servo.handle(Duration::ZERO, Request::Ping, Addressing::default()).reply.expect("a ping answers");
        assert_eq!(u16::from_le_bytes([ping[0], ping[1]]), profile.model.model_number, "{}", path.display());
        // Full PWM on a free shaft at the rated voltage: the page's no-load speed, within 2 %.
        let pwm = profile.operating_modes.pwm;
        let limit = profile.items[profile.index("pwm_limit")].spec.default.expect("a PWM limit");
        write(&mut servo, 11, &[pwm]).expect("PWM mode is allowed");
        write(&mut servo, 64, &[1]).expect("torque on");
        write(&mut servo, 100, &(limit as i16).to_le_bytes()).expect("Goal PWM");
        let mut load = BenchLoad::new(0.0);
        run(&mut servo, &mut load, 0.5);
        let rpm = load.state().velocity_rad_s * 60.0 / TAU;
        let page = profile.motor.no_load_speed_rpm;
        assert!((rpm - page).abs() / page < 0.02, "{}: {rpm:.2} rev/min at full PWM, the page says {page}", path.display());
    }
}

#[test]
fn every_profiles_servo_holds_a_velocity_and_a_position_with_its_factory_gains() {
    for (path, _) in profiles() {
        let profile = Arc::new(FirmwareProfile::load(&path).expect("loads"));
        let volts = profile.motor.rated_voltage_v;
        // Velocity mode: a quarter of the no-load speed, held by the factory PI gains.
        let mut servo = Servo::new(Arc::clone(&profile), 1, 1, volts);
        let rpm_per_unit = profile.items[profile.index("goal_velocity")].spec.scale.expect("a velocity unit");
        let goal = (profile.motor.no_load_speed_rpm / 4.0 / rpm_per_unit).round() as i32;
        write(&mut servo, 11, &[profile.operating_modes.velocity]).expect("velocity mode");
        write(&mut servo, 64, &[1]).expect("torque on");
        write(&mut servo, 104, &goal.to_le_bytes()).expect("Goal Velocity");
        let mut load = BenchLoad::new(0.0);
        run(&mut servo, &mut load, 3.0);
        let present = i32::from_le_bytes(read(&mut servo, 128, 4).try_into().expect("four bytes"));
        assert!((present - goal).abs() <= 2 + goal / 50, "{}: Present Velocity {present} for a goal of {goal}", path.display());
        // Position mode: a quarter turn, reached by the factory PID gains.
        let mut servo = Servo::new(Arc::clone(&profile), 1, 1, volts);
        write(&mut servo, 64, &[1]).expect("torque on");
        write(&mut servo, 116, &3072i32.to_le_bytes()).expect("Goal Position");
        let mut load = BenchLoad::new(0.0);
        run(&mut servo, &mut load, 3.0);
        let present = i32::from_le_bytes(read(&mut servo, 132, 4).try_into().expect("four bytes"));
        assert!((present - 3072).abs() <= 10, "{}: Present Position {present} for a goal of 3072", path.display());
    }
}

#[test]
fn a_model_without_current_sensing_reads_load_and_refuses_current_modes() {
    let profile = Arc::new(FirmwareProfile::load(&profiles_dir().join("xl430-w250.toml")).expect("loads"));
    assert!(profile.find("goal_current").is_none() && profile.find("current_limit").is_none(), "the XL430 has no current items");
    let mut servo = Servo::new(Arc::clone(&profile), 1, 1, 12.0);
    assert_eq!(write(&mut servo, 11, &[0]), Err(DeviceError::DataRange), "no current control mode");
    assert_eq!(write(&mut servo, 11, &[5]), Err(DeviceError::DataRange), "no current-based position mode");
    // Goal Current's address is a gap in this table: a write there alone reaches no item.
    assert!(write(&mut servo, 102, &[10, 0]).is_err(), "Goal Current does not exist");
    write(&mut servo, 11, &[1]).expect("velocity mode");
    write(&mut servo, 64, &[1]).expect("torque on");
    write(&mut servo, 104, &200i32.to_le_bytes()).expect("Goal Velocity");
    let mut load = BenchLoad::new(0.002);
    run(&mut servo, &mut load, 0.02);
    let load_permille = i16::from_le_bytes(read(&mut servo, 126, 2).try_into().expect("two bytes"));
    assert!((1..=1000).contains(&load_permille), "Present Load while accelerating: {load_permille}");
}

#[test]
fn x330_counts_current_in_milliamps() {
    let profile = Arc::new(FirmwareProfile::load(&profiles_dir().join("xl330-m288.toml")).expect("loads"));
    let goal_current = &profile.items[profile.index("goal_current")];
    assert_eq!((goal_current.address(), goal_current.spec.scale), (102, Some(1.0)));
    let mut servo = Servo::new(Arc::clone(&profile), 1, 1, profile.motor.rated_voltage_v);
    write(&mut servo, 11, &[0]).expect("current mode");
    write(&mut servo, 64, &[1]).expect("torque on");
    write(&mut servo, 102, &100i16.to_le_bytes()).expect("Goal Current 100 mA");
    // Held still: the winding current is the goal (the shaft against a large inertia).
    let mut load = BenchLoad::new(10.0);
    run(&mut servo, &mut load, 0.01);
    let present = i16::from_le_bytes(read(&mut servo, 126, 2).try_into().expect("two bytes"));
    assert!((present - 100).abs() <= 2, "Present Current {present} mA for a goal of 100 mA");
}
