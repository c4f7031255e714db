//! /proc/PID/stat, read by field: the watchdog judges a controller's threads by their state and
//! CPU time, and the run's end waits while the controller's process works.

/// The fields read (proc(5) numbers them from 1): the state (`R` running, `D` in the disk, `Z`
/// a zombie, …), the process group, and the CPU time in user and kernel mode (clock ticks).
pub const STATE: usize = 3;
pub const PGRP: usize = 5;
pub const UTIME: usize = 14;
pub const STIME: usize = 15;

/// Field `n` (1-based, as proc(5) numbers them) of a /proc/PID/stat line; the command name (2)
/// may hold spaces and parentheses, so fields after it are counted from its closing one.
pub fn stat_field(stat: &str, n: usize) -> Option<&str> {
    let close = stat.rfind(')')?;
    match n {
        1 => stat.split(' ').next(),
        2 => stat.get(stat.find('(')? + 1..close),
        _ => stat[close + 1..].split_whitespace().nth(n.checked_sub(3)?),
    }
}

/// User and kernel CPU time together (clock ticks) of a /proc/PID/stat line.
pub fn cpu_ticks(stat: &str) -> Option<u64> {
    let ticks = |n| stat_field(stat, n)?.parse::<u64>().ok();
    Some(ticks(UTIME)? + ticks(STIME)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_fields_are_counted_after_the_command_name() {
        let stat = "4242 (a (b) c) S 1 4240 4240 0 -1 4194304 10 0 0 0 7 5 0 0 20 0";
        assert_eq!(stat_field(stat, 1), Some("4242"));
        assert_eq!(stat_field(stat, 2), Some("a (b) c"));
        assert_eq!(stat_field(stat, STATE), Some("S"));
        assert_eq!(stat_field(stat, PGRP), Some("4240"));
        assert_eq!(cpu_ticks(stat), Some(12));
        assert_eq!(stat_field(stat, 0), None, "fields are numbered from 1");
        assert_eq!(stat_field("no parenthesis", STATE), None);
    }
}
