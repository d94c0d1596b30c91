//! From a placement to a sensor rig, and the rig's dataset.

use crate::error::{Result, StudyError};
use crate::study::Study;
use hilo_core::Valid;
use hilo_dataset::simulate::{RigSensor, SimulateConfig, WriteSummary, write_dataset};
use hilo_placement_ip::Placement;
use hilo_raycast::{QueryRegion, Scene, World};
use hilo_sensor_models::{Catalog, SensorSpec};
use std::path::Path;

/// The rig of a placement: LiDARs first (LIDAR_0, …), then radars (RADAR_0, …). `source` names
/// the placement in errors.
pub fn rig(placement: &Placement, catalog: &Catalog, scene: &Scene, source: &Path) -> Result<Vec<RigSensor>> {
    let mut lidars = Vec::new();
    let mut radars = Vec::new();
    for (i, s) in placement.sensors.iter().enumerate() {
        let spec = catalog
            .get(&s.ty)
            .map_err(|e| {
                StudyError::from(hilo_core::fs::FileError::Content {
                    path: source.to_path_buf(),
                    message: format!("sensors[{i}].type = {:?}: {e}", s.ty),
                })
            })?
            .clone();
        let p = s.pose.position;
        if !s.pose.is_valid() {
            return Err(StudyError::from(hilo_core::fs::FileError::Content {
                path: source.to_path_buf(),
                message: format!("sensors[{i}].pose is not finite: {:?}", s.pose),
            }));
        }
        if let Some(why) = outside(scene, &s.pose) {
            return Err(StudyError::from(hilo_core::fs::FileError::Content {
                path: source.to_path_buf(),
                message: format!("sensors[{i}].pose.position = {p} {why}"),
            }));
        }
        match spec {
            SensorSpec::Lidar(_) => lidars.push((spec, s.pose)),
            SensorSpec::Radar(_) => radars.push((spec, s.pose)),
        }
    }
    let mut rig: Vec<RigSensor> = lidars
        .into_iter()
        .enumerate()
        .map(|(k, (spec, pose))| RigSensor { channel: format!("LIDAR_{k}"), spec, pose })
        .collect();
    rig.extend(radars.into_iter().enumerate().map(|(k, (spec, pose))| RigSensor {
        channel: format!("RADAR_{k}"),
        spec,
        pose,
    }));
    Ok(rig)
}

/// The static world around a rig (everything within the sensors' ranges).
pub fn rig_world(scene: &Scene, rig: &[RigSensor]) -> Result<World> {
    let spheres = rig.iter().map(|s| {
        let r = match &s.spec {
            SensorSpec::Lidar(l) => l.max_range_m,
            SensorSpec::Radar(r) => r.max_range_m,
        };
        (s.pose.position, r)
    });
    Ok(World::build(scene, &QueryRegion::spheres(spheres))?)
}

/// Simulates and writes the dataset of a placement (resumable; see
/// [`hilo_dataset::simulate::write_dataset`]), after checking the placement was made for this
/// study's scene and catalog. `progress` hears the key frames written so far.
/// Why a sensor pose cannot be simulated on `scene` (more than 500 m from its origin, or below
/// its ground), or None.
pub fn outside(scene: &hilo_raycast::Scene, pose: &hilo_sensor_models::SensorPose) -> Option<String> {
    let p = pose.position;
    if p.truncate().length() > 500.0 {
        Some("is outside the scene (more than 500 m from its origin)".into())
    } else if p.z < scene.ground.z_m {
        Some(format!("is below the ground of the scene (z = {} m)", scene.ground.z_m))
    } else {
        None
    }
}

pub fn simulate(
    study: &Study,
    placement: &Placement,
    source: &Path,
    cfg: &Valid<SimulateConfig>,
    out: &Path,
    version: &str,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<WriteSummary> {
    placement.check_made_for(&study.scene_hash, &study.catalog_hash, source)?;
    let rig = rig(placement, &study.catalog, &study.scene, source)?;
    let world = rig_world(&study.scene, &rig)?;
    Ok(write_dataset(&study.scene, &world, &rig, cfg, out, version, &placement.name, progress)?)
}
