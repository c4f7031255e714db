//! Relocation between welds (seed report §6): an occupancy grid of the ground in plan (x, z), the
//! cells the robot cannot enter (obstacles, terrain it cannot climb, LIDAR returns) grown by its
//! half-width, and the shortest 8-connected path across it by A*. The search is the
//! `pathfinding` crate's (a well-kept, widely used implementation; the brief asks for one rather
//! than our own); this module only says what a cell, a move and its cost are.
//!
//! Costs are integers (micrometres), so that A*'s ordering is exact: a straight move costs one
//! cell, a diagonal one √2 cells rounded up, and the heuristic (the octile distance, rounded
//! down) never overestimates, so the path found is a shortest one on the grid. A diagonal move
//! may not cut a blocked corner: both cells beside it must be free.

use pathfinding::prelude::astar;
use thiserror::Error;

/// The most cells a grid may have (a 100 m square at 5 cm is 4 M): enough for a ship's deck
/// section, small enough that a mistaken cell size is an error, not an exhausted memory.
pub const MAX_CELLS: usize = 4_000_000;

#[derive(Debug, Error, PartialEq)]
pub enum PlanError {
    #[error("occupancy grid: cell size {cell_m} m and bounds {min:?}..{max:?} m give {cells} cells (at most {MAX_CELLS}), or are not finite and positive")]
    Grid { min: [f32; 2], max: [f32; 2], cell_m: f32, cells: f64 },
    #[error("the {which} ({x:.3}, {z:.3}) m is outside the occupancy grid")]
    OutOfBounds { which: &'static str, x: f32, z: f32 },
    #[error("the {which} ({x:.3}, {z:.3}) m is in a blocked cell (an obstacle, or within the robot's half-width of one)")]
    Blocked { which: &'static str, x: f32, z: f32 },
    #[error("no path from ({from_x:.3}, {from_z:.3}) to ({to_x:.3}, {to_z:.3}) m: the free cells do not connect them")]
    NoPath { from_x: f32, from_z: f32, to_x: f32, to_z: f32 },
}

/// Free and blocked cells over a rectangle of the ground; row along z, column along x.
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyGrid {
    /// (x, z) of cell (0, 0)'s lower corner.
    min: [f32; 2],
    cell_m: f32,
    cols: usize,
    rows: usize,
    blocked: Vec<bool>,
}

/// A planned path: cell centres from start to goal, and its length.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPath {
    pub points: Vec<[f32; 2]>,
    pub length_m: f32,
}

type Cell = (usize, usize);

impl OccupancyGrid {
    /// An all-free grid covering `min`..`max` (x, z) in cells of `cell_m`.
    pub fn new(min: [f32; 2], max: [f32; 2], cell_m: f32) -> Result<Self, PlanError> {
        let cols = ((max[0] - min[0]) / cell_m).ceil();
        let rows = ((max[1] - min[1]) / cell_m).ceil();
        let cells = f64::from(cols) * f64::from(rows);
        if !(cell_m > 0.0 && cols.is_finite() && rows.is_finite() && cols >= 1.0 && rows >= 1.0 && cells <= MAX_CELLS as f64) {
            return Err(PlanError::Grid { min, max, cell_m, cells });
        }
        let (cols, rows) = (cols as usize, rows as usize);
        Ok(Self { min, cell_m, cols, rows, blocked: vec![false; cols * rows] })
    }

    pub fn cell_m(&self) -> f32 {
        self.cell_m
    }

    /// Block every cell whose centre `blocked(x, z)` says the robot cannot stand on.
    pub fn block_where(&mut self, blocked: impl Fn(f32, f32) -> bool) {
        for row in 0..self.rows {
            for col in 0..self.cols {
                let [x, z] = self.centre((col, row));
                if blocked(x, z) {
                    self.blocked[row * self.cols + col] = true;
                }
            }
        }
    }

    /// Block the cell holding (x, z) (a LIDAR return); outside the grid nothing happens.
    pub fn block_point(&mut self, x: f32, z: f32) {
        if let Some((col, row)) = self.cell_of(x, z) {
            self.blocked[row * self.cols + col] = true;
        }
    }

    /// This grid with every blocked cell grown by `radius_m` (cells whose centres lie within it
    /// of a blocked cell's centre): the robot, planned as a point, then keeps its half-width off
    /// everything.
    pub fn inflated(&self, radius_m: f32) -> Self {
        let reach = (radius_m / self.cell_m).floor() as isize;
        let mut grown = self.clone();
        for row in 0..self.rows {
            for col in 0..self.cols {
                if !self.blocked[row * self.cols + col] {
                    continue;
                }
                for dr in -reach..=reach {
                    for dc in -reach..=reach {
                        let distance = self.offset_m(dc, dr);
                        let (r, c) = (row as isize + dr, col as isize + dc);
                        if distance <= radius_m && r >= 0 && c >= 0 && (r as usize) < self.rows && (c as usize) < self.cols {
                            grown.blocked[r as usize * self.cols + c as usize] = true;
                        }
                    }
                }
            }
        }
        grown
    }

    /// Whether the centres of the cells holding `a` and `b` lie within `radius_m` of each other:
    /// the rule by which [`OccupancyGrid::inflated`] grows a blocked cell. False outside the grid.
    pub fn cells_within(&self, a: [f32; 2], b: [f32; 2], radius_m: f32) -> bool {
        let (Some(ca), Some(cb)) = (self.cell_of(a[0], a[1]), self.cell_of(b[0], b[1])) else { return false };
        self.offset_m(ca.0 as isize - cb.0 as isize, ca.1 as isize - cb.1 as isize) <= radius_m
    }

    /// The distance between the centres of two cells `dc` columns and `dr` rows apart.
    fn offset_m(&self, dc: isize, dr: isize) -> f32 {
        ((dr * dr + dc * dc) as f32).sqrt() * self.cell_m
    }

    /// Whether (x, z) is blocked; everything outside the grid is.
    pub fn is_blocked(&self, x: f32, z: f32) -> bool {
        self.cell_of(x, z).is_none_or(|(col, row)| self.blocked[row * self.cols + col])
    }

    /// The distance from (x, z) to the nearest blocked cell's centre, looking `search_m` round
    /// it (`search_m` when none is that close).
    pub fn clearance_m(&self, x: f32, z: f32, search_m: f32) -> f32 {
        let reach = (search_m / self.cell_m).ceil() as isize + 1;
        let Some((col, row)) = self.cell_of(x, z) else { return 0.0 };
        let mut nearest = search_m;
        for dr in -reach..=reach {
            for dc in -reach..=reach {
                let (r, c) = (row as isize + dr, col as isize + dc);
                if r < 0 || c < 0 || r as usize >= self.rows || c as usize >= self.cols || !self.blocked[r as usize * self.cols + c as usize] {
                    continue;
                }
                let [cx, cz] = self.centre((c as usize, r as usize));
                nearest = nearest.min((cx - x).hypot(cz - z));
            }
        }
        nearest
    }

    /// The shortest 8-connected path of free cells from the cell holding `from` to the one
    /// holding `to`, as cell centres with `from` and `to` themselves at its ends.
    pub fn plan(&self, from: [f32; 2], to: [f32; 2]) -> Result<PlannedPath, PlanError> {
        let start = self.free_cell("start", from)?;
        let goal = self.free_cell("goal", to)?;
        let straight = (f64::from(self.cell_m) * 1e6).round() as u64;
        let diagonal = (f64::from(self.cell_m) * 1e6 * std::f64::consts::SQRT_2).ceil() as u64;
        let octile = |&(c, r): &Cell| {
            let (dx, dz) = (c.abs_diff(goal.0) as u64, r.abs_diff(goal.1) as u64);
            let (long, short) = (dx.max(dz), dx.min(dz));
            // √2 − 1 rounded down keeps the estimate admissible.
            (long - short) * straight + short * (diagonal.saturating_sub(1))
        };
        let successors = |&(c, r): &Cell| {
            let mut next = Vec::with_capacity(8);
            for (dc, dr) in [(-1isize, 0isize), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1)] {
                let (nc, nr) = (c as isize + dc, r as isize + dr);
                if !self.free(nc, nr) {
                    continue;
                }
                if dc != 0 && dr != 0 {
                    // No cutting a blocked corner.
                    if !self.free(c as isize + dc, r as isize) || !self.free(c as isize, r as isize + dr) {
                        continue;
                    }
                    next.push(((nc as usize, nr as usize), diagonal));
                } else {
                    next.push(((nc as usize, nr as usize), straight));
                }
            }
            next
        };
        let (cells, _) = astar(&start, successors, octile, |cell| *cell == goal).ok_or(PlanError::NoPath { from_x: from[0], from_z: from[1], to_x: to[0], to_z: to[1] })?;
        let mut points: Vec<[f32; 2]> = cells.iter().map(|&cell| self.centre(cell)).collect();
        // The ends are the poses asked for, not their cells' centres.
        if let Some(first) = points.first_mut() {
            *first = from;
        }
        if let Some(last) = points.last_mut() {
            *last = to;
        }
        if points.len() == 1 {
            points.push(to);
        }
        let length_m = points.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])).sum();
        Ok(PlannedPath { points, length_m })
    }

    /// [`OccupancyGrid::plan`] from `from`, or, when `from` is blocked (a robot that ended a weld
    /// closer to an obstacle than the clearance), from the nearest free cell within half a metre:
    /// the path then starts at `from` and steps out to that cell first.
    pub fn plan_from_nearest_free(&self, from: [f32; 2], to: [f32; 2]) -> Result<PlannedPath, PlanError> {
        let Some((col, row)) = self.cell_of(from[0], from[1]).filter(|&(c, r)| !self.free(c as isize, r as isize)) else { return self.plan(from, to) };
        let reach = (0.5 / self.cell_m).ceil() as isize;
        let nearest =
            (-reach..=reach).flat_map(|dr| (-reach..=reach).map(move |dc| (dc, dr))).filter(|&(dc, dr)| self.free(col as isize + dc, row as isize + dr)).min_by_key(|&(dc, dr)| dc * dc + dr * dr);
        let Some((dc, dr)) = nearest else { return self.plan(from, to) };
        let exit = self.centre(((col as isize + dc) as usize, (row as isize + dr) as usize));
        let mut path = self.plan(exit, to)?;
        path.length_m += (exit[0] - from[0]).hypot(exit[1] - from[1]);
        path.points.insert(0, from);
        Ok(path)
    }

    fn free_cell(&self, which: &'static str, [x, z]: [f32; 2]) -> Result<Cell, PlanError> {
        let cell = self.cell_of(x, z).ok_or(PlanError::OutOfBounds { which, x, z })?;
        if self.blocked[cell.1 * self.cols + cell.0] {
            return Err(PlanError::Blocked { which, x, z });
        }
        Ok(cell)
    }

    fn free(&self, col: isize, row: isize) -> bool {
        col >= 0 && row >= 0 && (col as usize) < self.cols && (row as usize) < self.rows && !self.blocked[row as usize * self.cols + col as usize]
    }

    fn cell_of(&self, x: f32, z: f32) -> Option<Cell> {
        let (c, r) = ((x - self.min[0]) / self.cell_m, (z - self.min[1]) / self.cell_m);
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.cols && (r as usize) < self.rows).then_some((c as usize, r as usize))
    }

    fn centre(&self, (col, row): Cell) -> [f32; 2] {
        [self.min[0] + (col as f32 + 0.5) * self.cell_m, self.min[1] + (row as f32 + 0.5) * self.cell_m]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> OccupancyGrid {
        OccupancyGrid::new([-1.0, -1.0], [3.0, 1.0], 0.05).unwrap()
    }

    #[test]
    fn on_open_ground_the_path_is_the_straight_line() {
        // Along a row of cell centres.
        let path = grid().plan([-0.475, 0.025], [2.475, 0.025]).unwrap();
        assert!((path.length_m - 2.95).abs() < 1e-4, "{}", path.length_m);
        // Ends off the centres cost at most the jog to and from their cells' centres.
        let path = grid().plan([-0.5, 0.0], [2.5, 0.0]).unwrap();
        assert!(path.length_m >= 3.0 && path.length_m < 3.0 + 0.02, "{}", path.length_m);
        // A diagonal: 8-connected moves follow it exactly.
        let path = grid().plan([0.025, 0.025], [0.525, 0.525]).unwrap();
        assert!((path.length_m - 0.5 * std::f32::consts::SQRT_2).abs() < 1e-4, "{}", path.length_m);
    }

    #[test]
    fn a_wall_with_a_gap_is_passed_through_the_gap_and_never_through_the_wall() {
        let mut g = grid();
        // A wall across x = 1.0, the whole grid wide but for a 0.4 m gap from z = 0.2 to 0.6.
        g.block_where(|x, z| (x - 1.0).abs() < 0.05 && !(0.2..0.6).contains(&z));
        let path = g.plan([0.0, 0.0], [2.0, 0.0]).unwrap();
        assert!(path.points.iter().all(|&[x, z]| !g.is_blocked(x, z)));
        let through = path.points.iter().find(|p| (p[0] - 1.0).abs() < 0.05).unwrap();
        assert!((0.2..0.6).contains(&through[1]), "crossed at z = {}", through[1]);
        // At least the two straight legs to the gap's near corner, at most 10 % more.
        let legs = 2.0 * (1.0f32 + 0.2 * 0.2).sqrt();
        assert!(path.length_m >= legs - 0.05 && path.length_m <= legs * 1.10, "{} vs {legs}", path.length_m);
        // Grown by 0.25 m from each side, the 0.4 m gap is closed: no path.
        let grown = g.inflated(0.25);
        assert!(matches!(grown.plan([0.0, 0.0], [2.0, 0.0]), Err(PlanError::NoPath { .. })));
    }

    #[test]
    fn ends_in_or_out_of_the_grid_and_bad_grids_are_named() {
        let mut g = grid();
        g.block_point(1.0, 0.0);
        assert_eq!(g.plan([1.01, 0.01], [2.0, 0.0]), Err(PlanError::Blocked { which: "start", x: 1.01, z: 0.01 }));
        assert_eq!(g.plan([0.0, 0.0], [5.0, 0.0]), Err(PlanError::OutOfBounds { which: "goal", x: 5.0, z: 0.0 }));
        assert!(OccupancyGrid::new([0.0, 0.0], [1000.0, 1000.0], 0.01).is_err());
        assert!(OccupancyGrid::new([0.0, 0.0], [1.0, 1.0], 0.0).is_err());
        assert!(OccupancyGrid::new([0.0, 0.0], [f32::NAN, 1.0], 0.1).is_err());
        assert!(g.is_blocked(-5.0, 0.0), "outside the grid is blocked");
    }

    #[test]
    fn inflation_grows_by_the_radius_and_clearance_measures_to_the_nearest_blocked_cell() {
        let mut g = grid();
        g.block_point(1.0, 0.0);
        let grown = g.inflated(0.1);
        assert!(grown.is_blocked(1.0 + 0.09, 0.0) && grown.is_blocked(1.0, 0.09));
        assert!(!grown.is_blocked(1.0 + 0.15, 0.0) && !grown.is_blocked(1.13, 0.08));
        // The blocked cell's centre is (1.025, 0.025).
        assert!((g.clearance_m(1.525, 0.025, 1.0) - 0.5).abs() < 1e-5);
        assert_eq!(g.clearance_m(2.9, 0.9, 0.2), 0.2);
    }
}
