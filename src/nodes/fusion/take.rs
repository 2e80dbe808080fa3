//! A camera's frame taken into its fused frame: checked against the limits, the dictionary's joints and its camera, its scores dequantised once into the buffer of the fused frame nearest its capture time; a camera whose clock jumped, or all of them (a replay started again).

use super::*;

impl FusionNode {
    pub(super) fn take(
        &mut self,
        camera: usize,
        msg: &HeatMaps,
        now_ns: i64,
    ) -> Result<Taken, NodeError> {
        let sequence = msg.sequence;
        let refuse = |reason: String| NodeError::Camera { sequence, reason };
        let Some(c) = self.cameras.get(camera) else {
            return Err(refuse(format!("no camera {camera}")));
        };
        let name = c.name.clone();
        self.limits
            .heatmap_values(
                msg.joint_names.len() as u64,
                u64::from(msg.height),
                u64::from(msg.width),
            )
            .map_err(|source| NodeError::Limit { sequence, source })?;
        if !same_layout(&msg.joint_names, &self.joint_names) {
            return Err(NodeError::Joints {
                sequence,
                found: msg.joint_names.clone(),
                expected: self.joint_names.clone(),
            });
        }
        let crop = msg.crop()?;
        if msg.track_id == 0 {
            return Err(refuse(format!(
                "camera {name}: track id 0 (unknown): the fusion matches each camera's \
                 tracks, which need ids of their own (the detector's tracker gives them)"
            )));
        }
        // The scores, dequantised and checked before the frame changes anything.
        msg.values_into(&mut self.decoded)?;
        let cells = msg.joint_names.len() * msg.height as usize * msg.width as usize;
        if self.decoded.len() != cells || cells == 0 {
            return Err(refuse(format!(
                "camera {name}: {} scores for {} maps of {} x {}",
                self.decoded.len(),
                msg.joint_names.len(),
                msg.height,
                msg.width
            )));
        }
        // A well-formed frame: its frame id is its camera's from now on.
        let frame = msg.header.frame_id.trim_start_matches('/');
        if frame.is_empty() && self.cameras[camera].frame_id.is_none() {
            return Err(refuse(format!("camera {name}: no frame id")));
        }
        if self.claim_frame(camera, frame).map_err(refuse)? {
            self.update_rig();
        }
        let c = &self.cameras[camera];
        if c.calibrated().is_none() {
            return Err(NodeError::Uncalibrated {
                sequence,
                camera: name,
                what: match (c.intrinsics.is_some(), self.extrinsics) {
                    (false, _) => "its CameraInfo (or [fusion.intrinsics])".into(),
                    (true, ExtrinsicsSource::Tf) => format!(
                        "its pose: {} to {} on TF",
                        self.world_frame,
                        c.frame_id.as_deref().unwrap_or("?")
                    ),
                    (true, ExtrinsicsSource::Config) => "its pose in [fusion.poses]".into(),
                },
            });
        }
        let stamp = msg.header.stamp.nanos();
        let (mut index, mut offset_ns) = self.place(stamp);
        // A frame far from the fused frames' time: its camera's clock is off (refused
        // while the others send on time), or the time started again (a replay, a clock
        // reset): once most cameras have sent `JUMP_FRAMES` such frames in a row, the
        // fused frames start again.
        let far = MAX_PENDING as i64;
        if index < self.next_index - far || index > self.next_index + far {
            let c = &mut self.cameras[camera];
            c.off_clock = (c.off_clock.0 + 1, Some(now_ns));
            let recent = |t: Option<i64>| t.is_some_and(|t| now_ns - t < self.wait_ns.max(1));
            let jumped = |c: &Camera| c.off_clock.0 >= JUMP_FRAMES && recent(c.off_clock.1);
            let off = self.cameras.iter().filter(|c| jumped(c)).count();
            let on = self
                .cameras
                .iter()
                .filter(|c| recent(c.heard_ns) && !recent(c.off_clock.1))
                .count();
            if off > 0 && off > on {
                return Ok(Taken::Restart);
            }
            if index > self.next_index {
                let seconds = (index - self.next_index) as f64 * self.period_ns as f64 * 1e-9;
                return Err(NodeError::Clock {
                    sequence,
                    camera: name,
                    seconds,
                });
            }
        }
        if index < self.next_index {
            return Err(NodeError::Late {
                sequence,
                camera: name,
                behind_ms: (self.next_index - index) as f64 * self.period_ns as f64 * 1e-6,
            });
        }
        // A camera faster than the fused frames, or whose clock runs about half a frame
        // off theirs, puts two frames in one and none in the next: one past the fused
        // frame's time, where one before it is there already, goes to the next.
        if offset_ns > 0
            && let Some(slot) = self.pending.iter().find(|s| s.index == index)
            && slot
                .frames
                .iter()
                .any(|f| f.camera == camera && f.track == msg.track_id && f.offset_ns < 0)
        {
            index += 1;
            offset_ns -= self.period_ns;
        }
        let p = self.pending.iter().position(|s| s.index >= index);
        let existing = p.filter(|&p| self.pending[p].index == index).and_then(|p| {
            self.pending[p]
                .frames
                .iter()
                .position(|f| f.camera == camera && f.track == msg.track_id)
                .map(|i| (p, i))
        });
        if existing.is_none() {
            // At most max_people tracks per camera and fused frame.
            let per_camera = p
                .filter(|&p| self.pending[p].index == index)
                .map_or(0, |p| {
                    self.pending[p]
                        .frames
                        .iter()
                        .filter(|f| f.camera == camera)
                        .count()
                });
            if per_camera >= self.settings.matching.max_people {
                return Err(refuse(format!(
                    "camera {name}: more than {} tracks in one frame \
                     (estimator.fusion.matching.max_people)",
                    self.settings.matching.max_people
                )));
            }
        }
        // Taken.
        let c = &mut self.cameras[camera];
        c.off_clock = (0, None);
        c.newest_ns = Some(c.newest_ns.map_or(stamp, |n| n.max(stamp)));
        c.heard_ns = Some(now_ns);
        c.frames += 1;
        self.counters.frames += 1;
        let frame = match existing {
            // A second frame of the track in this fused frame: the nearer one stays, the
            // other is counted.
            Some((p, i)) => {
                self.counters.superseded += 1;
                let f = &mut self.pending[p].frames[i];
                if f.offset_ns.abs() <= offset_ns.abs() {
                    return Ok(Taken::Frame);
                }
                f
            }
            None => {
                let p = match p {
                    Some(p) if self.pending[p].index == index => p,
                    at => {
                        let at = at.unwrap_or(self.pending.len());
                        self.pending.insert(
                            at,
                            Pending {
                                index,
                                first_heard_ns: now_ns,
                                frames: Vec::new(),
                            },
                        );
                        at
                    }
                };
                let frames = &mut self.pending[p].frames;
                let at = frames.len();
                frames.push(self.spare_frames.pop().unwrap_or_default());
                &mut frames[at]
            }
        };
        frame.camera = camera;
        frame.track = msg.track_id;
        frame.offset_ns = offset_ns;
        frame.crop = Some(crop);
        frame.height = msg.height as usize;
        frame.width = msg.width as usize;
        std::mem::swap(&mut frame.values, &mut self.decoded);
        Ok(Taken::Frame)
    }

    /// The fused frame nearest capture time `stamp` (the first stamp heard starts fused
    /// frame 0; half a period rounds up) and the offset from it, nanoseconds.
    pub(super) fn place(&mut self, stamp: i64) -> (i64, i64) {
        let epoch = *self.epoch_ns.get_or_insert(stamp);
        let index = (stamp - epoch + self.period_ns / 2).div_euclid(self.period_ns);
        (index, stamp - (epoch + index * self.period_ns))
    }

    /// The time started again (what waited was fused first): the people and the
    /// cameras' clocks are forgotten (their residuals stay counted, their ids are not
    /// given again); the next frame starts fused frame 0.
    pub(super) fn restart(&mut self) {
        tracing::warn!(
            "the cameras' capture times jumped (a replay started again, a clock reset): the \
             fused frames start again"
        );
        self.counters.restarts += 1;
        for mut slot in self.pending.drain(..) {
            self.spare_frames.append(&mut slot.frames);
        }
        let ended = &mut self.ended_residuals;
        for (_, w) in std::mem::take(&mut self.windows) {
            for (a, r) in ended.iter_mut().zip(w.residuals()) {
                a.merge(r);
            }
        }
        // Its ids go on: a body's id is never given twice.
        self.matcher.forget_all();
        self.epoch_ns = None;
        self.next_index = 0;
        for c in &mut self.cameras {
            c.newest_ns = None;
            c.heard_ns = None;
            c.off_clock = (0, None);
        }
    }
}
