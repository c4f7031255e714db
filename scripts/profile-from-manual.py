#!/usr/bin/env python3
"""Write a firmware profile from the e-manual's facts kept in firmware-profiles/e-manual/.

    python3 scripts/profile-from-manual.py MODEL [--name NAME] > firmware-profiles/MODEL.toml

MODEL.table.psv is the model page's control table as the e-manual writes it (a row per line:
address|size|name|access|default|range|unit); MODEL.facts.toml holds the page's specification
cells and section facts, its source and the day it was read, and the profile's deliberate
departures from the page ([deviations], each with why). Every address, size, access, default,
range and unit comes from the table; the motor's figures from the specification at the
recommended voltage. What the page does not say (the rotor inertia, the gearbox friction, the
thermal and overload model, the firmware's own timing) is chosen by one stated rule for every
model and marked "chosen" in the output. `tests/firmware_profiles.rs` checks the written profile
against the same two files, so a hand edit that drifts from the manual fails there.

The XM540-W270-R profile is the one the climbing robot's numbers were tuned on; it is written by
hand and kept (the test checks it against its page all the same).
"""

import math
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANUAL = ROOT / "firmware-profiles" / "e-manual"

# Units as profiles spell them.
UNITS = {"μsec": "us", "usec": "us", "°C": "degC", "V": "V", "%": "%", "mA": "mA", "msec": "ms", "ms": "ms",
         "pulse": "pulse", "rev/min": "rev/min", "rev/min²": "rev/min^2", "rev/min2": "rev/min^2"}
# Operating Mode values by the name the e-manual's section gives them.
MODE_NAMES = [("current-based", "current_based_position"), ("extended", "extended_position"), ("pwm", "pwm"),
              ("current", "current"), ("velocity", "velocity"), ("position", "position")]
# Every X-series model's Hardware Error Status bits (the e-manual's Shutdown(63) table).
ERROR_BITS = {"input_voltage": 0, "overheating": 2, "motor_encoder": 3, "electrical_shock": 4, "overload": 5}
# Items whose value the firmware writes: signed when their range may be negative.
SIGNED_PRESENT = {"present_pwm", "present_current", "present_load", "present_velocity", "present_position",
                  "velocity_trajectory", "position_trajectory", "homing_offset"}
# Control Table Backup saves the EEPROM area and these RAM items (the XM540 profile's choice).
BACKUP_RAM = {"velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain", "position_p_gain",
              "feedforward_2nd_gain", "feedforward_1st_gain", "profile_acceleration", "profile_velocity"}
EXTENDED_POSITION_RANGE = 1048575


def key_of(name):
    special = {"Secondary(Shadow) ID": "secondary_id", "Protocol Version": "protocol_type"}
    return special.get(name, re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_"))


def read_table(model):
    rows = []
    for line in (MANUAL / f"{model}.table.psv").read_text().splitlines():
        if not line.strip() or line.startswith("#") or line.startswith("address|"):
            continue
        address, size, name, access, default, range_, unit = [c.strip() for c in line.split("|")]
        rows.append({"address": int(address), "size": int(size), "name": name, "access": access,
                     "default": default, "range": range_, "unit": unit})
    return rows


def first(cell):
    """A cell with two readings (velocity- and time-based profile) means the first."""
    return cell.split(" / ")[0].strip()


def parse_range(cell, by_address):
    """(min, max, min_ref, max_ref) from a range cell."""
    cell = first(cell)
    if cell == "-":
        return None, None, None, None
    numbers = re.fullmatch(r"(-?\d+)\s*~\s*(-?\d+)", cell)
    if numbers:
        return int(numbers[1]), int(numbers[2]), None, None
    if re.fullmatch(r"\d+", cell):  # "3": the largest value (Startup Configuration's bits)
        return 0, int(cell), None, None
    refs = re.fullmatch(r"(-?)\s*[A-Za-z ]+\((\d+)\)\s*~\s*(-?)\s*[A-Za-z ]+\((\d+)\)", cell)
    if refs:
        low = ("-" if refs[1] else "") + by_address[int(refs[2])]
        high = ("-" if refs[3] else "") + by_address[int(refs[4])]
        return None, None, low, high
    raise SystemExit(f"cannot read range {cell!r}")


def parse_unit(cell):
    cell = first(cell)
    if cell == "-":
        return None, None
    match = re.fullmatch(r"([\d.]+)\s*\[(.+)\]", cell)
    if not match:
        raise SystemExit(f"cannot read unit {cell!r}")
    return float(match[1]), UNITS.get(match[2], match[2])


def at_voltage(cell, volts):
    """The reading of a specification cell ('1.5 [N.m] (at 12.0 [V], 1.4 [A]) / …') at `volts`."""
    for part in cell.split(" / "):
        match = re.match(r"([\d.]+)\s*\[[^\]]+\]\s*\(at\s*([\d.]+)\s*(?:\[V\])?[,\s]*(?:([\d.]+)\s*\[A\])?", part)
        if match and math.isclose(float(match[2]), volts):
            return float(match[1]), (float(match[3]) if match[3] else None)
    raise SystemExit(f"no reading at {volts} V in {cell!r}")


def expand_indirect(rows):
    """Every row, with the indirect entries the page elides ('…') written out, and the blocks.

    Entries n < m listed on the page belong to one block when Indirect Address m sits 2 (m - n)
    bytes after n's; a block holds every entry from its first listed number to its last."""
    numbered = {int(r["name"].split()[-1]): r for r in rows if r["name"].startswith("Indirect Address ")}
    data = {int(r["name"].split()[-1]): r for r in rows if r["name"].startswith("Indirect Data ")}
    spans = []
    for n in sorted(numbered):
        if spans and numbered[n]["address"] - numbered[spans[-1][0]]["address"] == 2 * (n - spans[-1][0]):
            spans[-1][1] = n
        else:
            spans.append([n, n])
    out = [r for r in rows if not r["name"].startswith("Indirect ")]
    blocks = []
    for start, end in spans:
        first_address, first_data = numbered[start], data[start]
        for n in range(start, end + 1):
            k = n - start
            out.append(numbered.get(n) or {**first_address, "address": first_address["address"] + 2 * k,
                                             "name": f"Indirect Address {n}", "default": str(first_data["address"] + k)})
            out.append(data.get(n) or {**first_data, "address": first_data["address"] + k, "name": f"Indirect Data {n}"})
        blocks.append({"address_start": first_address["address"], "data_start": first_data["address"], "count": end - start + 1})
    return out, blocks


def toml_value(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def main():
    model = sys.argv[1]
    facts = tomllib.loads((MANUAL / f"{model}.facts.toml").read_text())
    spec, sections, chosen = facts["specification"], facts["sections"], facts["chosen"]
    rows, blocks = expand_indirect(read_table(model))
    rows.sort(key=lambda r: r["address"])
    by_address = {r["address"]: key_of(r["name"]) for r in rows}
    rated_v = float(re.search(r"Recommended\s*:\s*([\d.]+)", spec["input_voltage"])[1])
    stall_torque, stall_current = at_voltage(spec["stall_torque"], rated_v)
    no_load_rpm, _ = at_voltage(spec["no_load_speed"], rated_v)
    gear_ratio = float(re.match(r"([\d.]+)", spec["gear_ratio"])[1])
    standby_a = float(re.match(r"([\d.]+)", spec["standby_current"])[1]) / 1000.0
    bauds = [(int(c), int(b)) for c, b in (p.split(":") for p in sections["baud_codes"].replace(" ", "").split(","))]
    modes = {}
    for part in sections["operating_mode_values"].split(","):
        code, name = part.split(":", 1)
        label = name.lower().replace(" ", "-")
        modes[next(key for word, key in MODE_NAMES if word in label)] = int(code)
    deviations = facts.get("deviations", {})

    # Chosen, one rule for every model: a 2 ms mechanical time constant at the horn (the XM540's),
    # gearbox friction at 0.28 % of stall torque (Coulomb) and 0.3 % of the back-EMF slope (viscous).
    # A model with identified friction ([identified] in its facts) takes that instead.
    no_load_rad_s = no_load_rpm * 2 * math.pi / 60
    back_emf = stall_torque / no_load_rad_s
    rotor_inertia = 0.002 * back_emf / gear_ratio ** 2
    coulomb, viscous = stall_torque * 0.0028, back_emf * 0.003
    identified = facts.get("identified")

    print(f"# Firmware profile: ROBOTIS Dynamixel {facts['model']['name']}.")
    print("#")
    print(f"# Written by scripts/profile-from-manual.py from firmware-profiles/e-manual/{model}.table.psv and")
    print(f"# {model}.facts.toml: the e-manual page {facts['source']['page']}")
    print(f"# ({facts['source']['file']} at commit {facts['source']['commit'][:12]}, read {facts['source']['read_on']}).")
    print("# Every item, the baud rates, the operating modes and the motor's datasheet figures are the page's;")
    print("# what the page does not give is marked \"chosen\". tests/firmware_profiles.rs checks this file")
    print("# against the page's facts.")
    print()
    print("[model]")
    print(f"name = {toml_value(facts['model']['name'])}")
    model_number = int(next(r for r in rows if r["address"] == 0)["default"])
    print(f"model_number = {model_number}")
    print(f"# Chosen: {chosen['firmware_version_why']}")
    print(f"firmware_version = {chosen['firmware_version']}")
    print("# Chosen: the Model Information content is undocumented; a fixed value is returned.")
    print("model_information = 0")
    print("# Chosen, as for every model: how long a rebooted servo stays silent (undocumented).")
    print("boot_time_ms = 100")
    print("# Chosen, as for every model: the firmware's control period, in-position and following-error windows.")
    print("control_period_us = 1000")
    print("in_position_window_pulses = 20")
    print("following_error_pulses = 512")
    print("bits_per_byte = 10")
    print("inter_byte_timeout_us = 1500")
    print()
    for code, bps in bauds:
        print(f"[[baud_rate]]\ncode = {code}\nbps = {bps}")
    print()
    print("[motor]")
    print(f"# The page's specification at the recommended {rated_v} V: {spec['stall_torque']}; {spec['no_load_speed']}.")
    print(f"rated_voltage_v = {rated_v}")
    print(f"stall_torque_nm = {stall_torque}")
    print(f"stall_current_a = {stall_current}")
    print(f"no_load_speed_rpm = {no_load_rpm}")
    print(f"# The page's standby current ({spec['standby_current']}), the no-load current floor.")
    print(f"standby_current_a = {standby_a}")
    print(f"gear_ratio = {gear_ratio}")
    print("pulses_per_rev = 4096")
    if identified:
        source = identified["source"]
        print(f"# Identified, not chosen: {source}. The rotor inertia is the identified armature")
        print(f"# ({identified['armature_kgm2']} kg·m² at the horn) over the gear ratio squared; Coulomb and viscous")
        print("# friction are its M1 (Coulomb-viscous) model, the one this servo model has.")
        print(f"rotor_inertia_kgm2 = {identified['armature_kgm2'] / gear_ratio ** 2:.4e}")
        print(f"coulomb_friction_nm = {identified['coulomb_friction_nm']}")
        print(f"viscous_friction_nm_per_rad_s = {identified['viscous_friction_nm_per_rad_s']}")
        slope = (stall_torque - identified["coulomb_friction_nm"]) / no_load_rad_s - identified["viscous_friction_nm_per_rad_s"]
        print("# The torque-speed slope that keeps the page's no-load speed with the identified friction.")
        print(f"back_emf_damping_nm_per_rad_s = {slope:.5g}")
    else:
        print("# Chosen: the rotor inertia that gives the horn a 2 ms mechanical time constant (the XM540-W270's).")
        print(f"rotor_inertia_kgm2 = {rotor_inertia:.3e}")
        print("# Chosen: gearbox friction, Coulomb 0.28 % of the stall torque and viscous 0.3 % of the back-EMF")
        print("# slope (the XM540-W270's proportions); no identified friction is published for this model.")
        print(f"coulomb_friction_nm = {coulomb:.4g}")
        print(f"viscous_friction_nm_per_rad_s = {viscous:.4g}")
    print("# Chosen, as for every model: the thermal and overload model.")
    print("thermal_resistance_c_per_w = 4.0")
    print("thermal_time_constant_s = 600.0")
    print("ambient_temperature_c = 25.0")
    print("overload_current_fraction = 0.9")
    print("overload_time_s = 2.0")
    print()
    print("[hardware_error_bits]")
    for name, bit in ERROR_BITS.items():
        print(f"{name} = {bit}")
    print()
    for block in blocks:
        print("[[indirect_block]]")
        for k, v in block.items():
            print(f"{k} = {v}")
        print()
    print("[operating_modes]")
    for name in ["current", "velocity", "position", "extended_position", "current_based_position", "pwm"]:
        if name in modes:
            print(f"{name} = {modes[name]}")
    print()

    rated_tenths = round(rated_v * 10)
    for row in rows:
        key = by_address[row["address"]]
        low, high, low_ref, high_ref = parse_range(row["range"], by_address)
        scale, unit = parse_unit(row["unit"])
        area = "eeprom" if row["address"] < 64 else "ram"
        item = {"key": key, "name": row["name"], "address": row["address"], "size": row["size"],
                "access": "R" if row["access"] == "R" else "RW", "area": area}
        default = row["default"]
        notes = []
        if re.fullmatch(r"-?\d+", default):
            value = int(default)
        else:
            # The page gives no value: what the firmware holds at power-on.
            value = {"firmware_version": chosen["firmware_version"], "goal_pwm": None, "goal_current": None,
                     "present_input_voltage": rated_tenths, "present_temperature": 25}.get(key, 0)
            if key == "goal_pwm":
                value = int(next(r for r in rows if key_of(r["name"]) == "pwm_limit")["default"])
            if key == "goal_current":
                value = int(next(r for r in rows if key_of(r["name"]) == "current_limit")["default"])
            notes.append("default not on the page: the power-on value")
        if key == "goal_position" and low_ref:
            # The position limits bound Goal Position in Position Control Mode only; the extended
            # modes take +-256 turns (the page's Goal Position section).
            low, high = -EXTENDED_POSITION_RANGE, EXTENDED_POSITION_RANGE
        departures = deviations.get(key, {})
        if "min" in departures or "max" in departures:
            # A departure bounds the item even where the page gives no range.
            low = departures.get("min", low if low is not None else 0)
            high = departures.get("max", high)
        if key in deviations:
            notes.append(f"departs from the page: {deviations[key]['why']}")
        item["default"] = departures.get("default", value)
        if low is not None:
            item["min"], item["max"] = low, high
        if low_ref:
            item["min_ref"], item["max_ref"] = low_ref, high_ref
            if key == "goal_position":
                item["refs_in_modes"] = [modes["position"]]
        if key == "operating_mode":
            item["values"] = sorted(modes.values())
        if (low is not None and low < 0) or (low_ref or "").startswith("-") or key in SIGNED_PRESENT:
            item["signed"] = True
        if key in facts.get("conversions", {}):
            # A gain: its section's divisor (the row gives no unit).
            unit, scale = None, 1.0 / facts["conversions"][key]
        if "scale" in departures:
            unit, scale = departures.get("unit"), departures["scale"]
        if unit:
            item["unit"] = unit
        if scale is not None:
            item["scale"] = scale
        if area == "eeprom" or key in BACKUP_RAM or key.startswith("indirect_address_"):
            item["backup"] = True
        if notes:
            item["note"] = "; ".join(notes) + "."
        print("[[item]]")
        for k, v in item.items():
            print(f"{k} = {toml_value(v)}")
        print()


if __name__ == "__main__":
    main()
