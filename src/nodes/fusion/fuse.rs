//! A fused frame made: the cameras' tracks matched into people, each person's views to their window, and its estimates as skeletons in the world frame.

use super::*;

impl FusionNode {
    /// Makes fused frame `slot`: matches its tracks into people, pushes each person's
    /// views into their window, appends the estimates' skeletons to `out`.
    pub(super) fn fuse(&mut self, mut slot: Pending, out: &mut Vec<Skeleton3D>) {
        self.next_index = self.next_index.max(slot.index + 1);
        let epoch = self.epoch_ns.unwrap_or(0);
        let stamp_ns = epoch + slot.index * self.period_ns;
        self.counters.fused += 1;
        // Frames of cameras that lost their calibration since (a TF change) wait no more.
        let cameras = &self.cameras;
        let spare = &mut self.spare_frames;
        let mut i = 0;
        while i < slot.frames.len() {
            if cameras[slot.frames[i].camera].calibrated().is_some() {
                i += 1;
            } else {
                spare.push(slot.frames.swap_remove(i));
            }
        }
        self.peaks.resize_with(slot.frames.len(), Vec::new);
        for (f, peaks) in slot.frames.iter().zip(self.peaks.iter_mut()) {
            match f.crop {
                Some(crop) => {
                    let to_image = crop.pixel_map(f.width, f.height);
                    peaks_into(&f.values, f.height, f.width, &to_image, peaks);
                }
                None => peaks.clear(),
            }
        }
        let observations: Vec<TrackObservation<'_>> = slot
            .frames
            .iter()
            .zip(&self.peaks)
            .map(|(f, peaks)| TrackObservation {
                view: f.camera,
                track: u64::from(f.track),
                peaks,
                box_size: f.crop.map_or(0.0, |c| c.width.max(c.height)),
            })
            .collect();
        self.matcher
            .assign(stamp_ns, &self.rig, &observations, &mut self.ids);
        drop(observations);
        self.counters.unmatched += self.ids.iter().filter(|i| i.is_none()).count() as u64;
        let mut people: Vec<u64> = self.ids.iter().flatten().copied().collect();
        people.sort_unstable();
        people.dedup();
        for id in people {
            let views: Vec<ViewMaps<'_>> = slot
                .frames
                .iter()
                .zip(&self.ids)
                .filter(|(_, m)| **m == Some(id))
                .filter_map(|(f, _)| {
                    Some(ViewMaps {
                        view: f.camera,
                        dt: f.offset_ns as f64 * 1e-9,
                        to_image: f.crop?.pixel_map(f.width, f.height),
                        height: f.height,
                        width: f.width,
                        values: Scores::F32(&f.values),
                    })
                })
                .collect();
            let window = match self.windows.entry(id) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => {
                    match FusedWindow::new(&self.estimator, self.rig.clone(), self.settings.clone())
                    {
                        Ok(w) => {
                            self.counters.people += 1;
                            e.insert(w)
                        }
                        Err(source) => {
                            let e = NodeError::Estimate {
                                sequence: slot.index as u64,
                                source,
                            };
                            self.refused.note(e.kind(), &e);
                            continue;
                        }
                    }
                }
            };
            self.estimates.clear();
            if let Err(source) = window.push(stamp_ns, &views, &mut self.estimates) {
                let e = NodeError::Estimate {
                    sequence: slot.index as u64,
                    source,
                };
                self.refused.note(e.kind(), &e);
                continue;
            }
            for v in &views {
                self.cameras[v.view].used += 1;
            }
            if let Some(newest) = self.estimates.iter().find(|e| e.lag == 0) {
                self.matcher.set_pose(id, &newest.joints);
            }
            for e in &self.estimates {
                if !e.joints.iter().chain(&e.joint_std).all(|v| v.is_finite()) {
                    let err = NodeError::NonFiniteOutput {
                        sequence: slot.index as u64,
                    };
                    self.refused.note(err.kind(), &err);
                    continue;
                }
                out.push(self.skeleton(id, e, epoch));
                self.counters.skeletons += 1;
            }
        }
        // People the matcher forgot: their windows go, their residuals stay counted.
        let known: Vec<u64> = self.matcher.people().collect();
        let ended = &mut self.ended_residuals;
        self.windows.retain(|id, w| {
            let keep = known.contains(id);
            if !keep {
                for (a, r) in ended.iter_mut().zip(w.residuals()) {
                    a.merge(r);
                }
            }
            keep
        });
        self.spare_frames.append(&mut slot.frames);
        self.check_extrinsics();
    }

    /// The skeleton of person `id`'s estimate `e`.
    pub(super) fn skeleton(&self, id: u64, e: &FusedEstimate, epoch: i64) -> Skeleton3D {
        let index = (e.stamp_ns - epoch).div_euclid(self.period_ns.max(1));
        Skeleton3D {
            header: Header {
                stamp: Time::from_nanos(e.stamp_ns),
                frame_id: self.world_frame.clone(),
            },
            sequence: index.max(0) as u64,
            // Ids from 1; 0 is \"unknown\" in the messages.
            track_id: ((id.max(1) - 1) % u64::from(u32::MAX)) as u32 + 1,
            joint_names: self.joint_names.clone(),
            units: Units::Metres as u8,
            positions: e.joints.clone(),
            position_std: e.joint_std.clone(),
            keypoints: Vec::new(),
            keypoint_std: Vec::new(),
            projected: Vec::new(),
            lag: e.lag as u32,
            state: SkeletonState::Tracking as u8,
            metric_source: if e.monocular {
                MetricSource::Size as u8
            } else {
                MetricSource::Views as u8
            },
            views: e
                .views
                .iter()
                .map(|&v| self.cameras[v].frame_id.clone().unwrap_or_default())
                .collect(),
            // Several cameras' looks: not told apart (msgs/msg/Skeleton3D.msg).
            frames_since_look: 0,
            // Measured from its bones, not assumed: see Skeleton3D.msg.
            mean_bone_length: 0.0,
        }
    }
}
