//! What the sensor server serves an external run's controller (`/line`, `/frame`, `/state`,
//! `/lidar`, `/welds`): published from the world after each tick.

use std::ops::ControlFlow;
use std::sync::{Arc, Mutex, PoisonError};

use serde_json::json;
use tracing::warn;

use crate::sensor_server::SensorFeed;
use crate::sim::RobotWorld;

use super::observe::{Observer, plan_pose, robot_relative};
use super::ticks::TickHook;

/// How often `/state` is published in a world without a weld line (with one, it comes with each
/// camera frame).
const STATE_RATE_HZ: f64 = 30.0;

/// What a world the watch gave up on (it left the terrain, lost every contact) does to the
/// loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WorldFailed {
    /// The run ends (a run's verdict).
    Ends,
    /// The world goes on (`serve`: the controller is whoever connects, and decides).
    GoesOn,
}

/// What the loop does after each tick of a world on the wall clock: events, camera and detector
/// (publishing each new frame, line measurement and ground truth), the time series and the
/// view. The first error is kept in `errors` (the loop cannot stop for it mid-tick).
pub fn observer_hook(observer: Arc<Mutex<Observer>>, feed: Arc<SensorFeed>, errors: Arc<Mutex<Option<String>>>, world_failed: WorldFailed) -> TickHook {
    let mut next_state_s = 0.0;
    let mut lidar_published = None;
    let mut welds_published = false;
    Box::new(move |bus, now| {
        let mut observer = observer.lock().unwrap_or_else(PoisonError::into_inner);
        let t_s = now.as_secs_f64();
        let observation = observer.on_tick(bus, now);
        let Some(world) = bus.plant::<RobotWorld>() else { return ControlFlow::Continue(()) };
        if let Some(error) = observation.error {
            errors.lock().unwrap_or_else(PoisonError::into_inner).get_or_insert(error.to_string());
        }
        if observation.new_frame {
            // In the run's one convention (as timeseries.csv's d_m): the robot relative to the
            // line, + = robot left of it.
            if let Some(latest) = observer.latest().copied() {
                let line = robot_relative(&latest);
                feed.publish_line(t_s, line.d_err_m, line.psi_err_rad, latest.valid);
            }
            if let Some(frame) = observer.camera().latest()
                && let Err(error) = feed.publish_frame(frame.width, frame.height, &frame.pixels)
            {
                warn!(%error, "camera frame not published");
            }
        }
        if !welds_published {
            welds_published = true;
            feed.publish_welds(observer.welds_json());
        }
        if let Some(scan) = observer.lidar_scan().filter(|scan| lidar_published != Some(scan.t)) {
            lidar_published = Some(scan.t);
            feed.publish_lidar(scan.to_json());
        }
        // Without a line there are no frames: the state keeps its own rate.
        if observation.new_frame || (!observer.has_line() && t_s >= next_state_s) {
            next_state_s = t_s + 1.0 / STATE_RATE_HZ;
            let pose = world.chassis_pose();
            let truth = observer.ground_truth(world);
            feed.publish_state(json!({
                "t": t_s,
                "x": pose.translation.x, "y": pose.translation.y, "z": pose.translation.z,
                "heading_rad": plan_pose(world).heading_rad,
                "d_err_m": truth.d_err_m, "psi_err_rad": truth.psi_err_rad, "speed_m_s": truth.speed_m_s,
                "weld": truth.weld,
            }));
        }
        if world_failed == WorldFailed::Ends && observer.world_failure().is_some() { ControlFlow::Break(()) } else { ControlFlow::Continue(()) }
    })
}
