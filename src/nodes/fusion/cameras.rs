//! The fusion node's cameras: their calibration (a `CameraInfo`, the configuration), their poses (TF, the configuration), and the check of their extrinsics against the fused poses.

use super::*;

impl FusionNode {
    /// Each camera: calibration, frames, residual against the fused poses, whether its
    /// extrinsics are suspect.
    pub fn cameras(&self) -> Vec<CameraReport> {
        let residuals = self.residuals();
        self.cameras
            .iter()
            .zip(&residuals)
            .enumerate()
            .map(|(v, (c, r))| CameraReport {
                name: c.name.clone(),
                frame_id: c.frame_id.clone().unwrap_or_default(),
                calibrated: c.calibrated().is_some(),
                frames: c.frames,
                used: c.used,
                residual: Some(r.mean()).filter(|m| m.is_finite()),
                residual_frames: r.frames,
                suspect: self.suspects.contains(&v),
            })
            .collect()
    }

    /// Every camera's residuals: the people forgotten and those tracked.
    pub(super) fn residuals(&self) -> Vec<ViewResidual> {
        let mut all = self.ended_residuals.clone();
        for w in self.windows.values() {
            for (a, r) in all.iter_mut().zip(w.residuals()) {
                a.merge(r);
            }
        }
        all
    }

    /// Takes camera `camera`'s calibration: its intrinsics (unless configured) and, the
    /// first time, its frame id. A calibration that cannot be used is refused
    /// (`camera-info`).
    pub fn camera_info(&mut self, camera: usize, info: &CameraInfo) {
        let result = crate::nodes::estimator::metres::calibration(info, &self.limits)
            .map(|(intrinsics, _)| intrinsics);
        let Some(name) = self.cameras.get(camera).map(|c| c.name.clone()) else {
            return;
        };
        match result {
            Ok(intrinsics) => {
                // An empty frame id names no frame: the calibration is still its camera's.
                let frame = info.header.frame_id.trim_start_matches('/');
                let mut changed = false;
                if !frame.is_empty() {
                    match self.claim_frame(camera, frame) {
                        Ok(claimed) => changed = claimed,
                        Err(reason) => {
                            let e = NodeError::CameraInfo { reason };
                            self.refused.note(e.kind(), &e);
                            return;
                        }
                    }
                }
                let c = &mut self.cameras[camera];
                if c.configured_intrinsics.is_none() && c.intrinsics != Some(intrinsics) {
                    c.intrinsics = Some(intrinsics);
                    changed = true;
                }
                if changed {
                    self.update_rig();
                }
            }
            Err(reason) => {
                let e = NodeError::CameraInfo {
                    reason: format!("camera {name}: {reason}"),
                };
                self.refused.note(e.kind(), &e);
            }
        }
    }

    /// Camera `camera`'s message is in `frame`: its own frame already (`Ok(false)`), or
    /// taken as its own now (`Ok(true)`); refused (the reason) when the camera has
    /// another, or when `frame` is another camera's (a mix-up of topics or of a camera's
    /// configuration), so that no camera becomes another's twin.
    pub(super) fn claim_frame(&mut self, camera: usize, frame: &str) -> Result<bool, String> {
        let name = &self.cameras[camera].name;
        if let Some(own) = &self.cameras[camera].frame_id {
            return if own == frame {
                Ok(false)
            } else {
                Err(format!(
                    "camera {name}: frame id {frame:?}, not its {own:?}"
                ))
            };
        }
        if let Some(other) = self
            .cameras
            .iter()
            .find(|c| c.frame_id.as_deref() == Some(frame))
        {
            return Err(format!(
                "camera {name}: frame id {frame:?} is camera {}'s: each camera needs a frame \
                 of its own",
                other.name
            ));
        }
        self.cameras[camera].frame_id = Some(frame.to_string());
        Ok(true)
    }

    /// Takes transforms (`/tf_static`, `/tf`): with extrinsics from TF, each camera's
    /// pose is `world_frame` to its frame. Transforms the buffer cannot hold are
    /// refused (`tf`); people's frames (ours, heard back) are passed over.
    pub fn transforms(&mut self, message: &TFMessage, topic: TfTopic) {
        if self.extrinsics != ExtrinsicsSource::Tf {
            return;
        }
        let wanted = |t: &msgs::tf::TransformStamped| {
            !crate::nodes::frames::is_body_transform(&t.header.frame_id, &t.child_frame_id)
        };
        for reason in self.tf.take_where(message, topic, wanted) {
            let e = NodeError::Transform { reason };
            self.refused.note(e.kind(), &e);
        }
        self.update_rig();
    }

    /// Looks the cameras' poses up (TF) and hands the windows every change.
    pub(super) fn update_rig(&mut self) {
        for (v, c) in self.cameras.iter_mut().enumerate() {
            if self.extrinsics == ExtrinsicsSource::Tf
                && let Some(frame) = &c.frame_id
            {
                c.pose = self.tf.lookup(&self.world_frame, frame);
            }
            let Some(now) = c.calibrated() else {
                continue;
            };
            if now.check().is_err() || now == self.rig[v] {
                continue;
            }
            self.rig[v] = now;
            for w in self.windows.values_mut() {
                // Checked above: cannot fail.
                let _ = w.set_camera(v, now);
            }
        }
    }

    /// Names the cameras whose extrinsics disagree with the others' (a warning when the
    /// set changes).
    pub(super) fn check_extrinsics(&mut self) {
        let now = suspects(&self.residuals(), &self.check);
        if now != self.suspects {
            for &v in now.iter().filter(|v| !self.suspects.contains(v)) {
                tracing::warn!(
                    "camera {}: its heat maps disagree with the fused poses' projections much \
                     more than the other cameras' do: its extrinsics (pose in {}) are likely \
                     wrong",
                    self.cameras[v].name,
                    self.world_frame
                );
            }
            self.suspects = now;
        }
    }
}
