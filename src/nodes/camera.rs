//! The calibration an image source without one is assumed to have: a pinhole camera of
//! `[detector.images] field_of_view` (horizontal, degrees) centred on each image, as
//! `sensor_msgs/CameraInfo`, so that skeletons of folders and videos come out in metres
//! (under that assumption, which docs/metric.md states). A real camera (`ros2` and
//! `image-recording` sources) has its own calibration on `topics.camera_info`.
//!
//! The detector's thread writes the calibration of each image into a [`CameraTap`]
//! when it changes (the first image, a folder's image of another size): the tap
//! publishes it to the outputs given to it ([`CameraTap::publish_to`]: ROS 2, the
//! recording) and keeps the newest for an estimator in the same process, which reads
//! it as a [`Source`] ([`CameraTap::reader`]) before the heat maps of that image.

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use super::service::Publishers;
use crate::images::ImageFrame;
use crate::msgs::sensor::CameraInfo;
use crate::msgs::{Header, Time};
use crate::transport::{Received, Source, TransportError};

/// The pinhole calibration a camera of horizontal field of view `fov_deg` has for
/// `frame`: square pixels, the principal point at the image's centre.
pub fn assumed_camera_info(frame: &ImageFrame, fov_deg: f64) -> CameraInfo {
    let (width, height) = (frame.rgb.width(), frame.rgb.height());
    let focal = 0.5 * f64::from(width) / (0.5 * fov_deg.to_radians()).tan();
    // Pixel centres at whole coordinates: the image's centre is at (w - 1) / 2.
    let (cx, cy) = (
        0.5 * (f64::from(width) - 1.0),
        0.5 * (f64::from(height) - 1.0),
    );
    CameraInfo {
        header: Header {
            stamp: Time::from_nanos(i64::try_from(frame.stamp_ns).unwrap_or(i64::MAX)),
            frame_id: frame.frame_id.clone(),
        },
        width,
        height,
        k: [focal, 0.0, cx, 0.0, focal, cy, 0.0, 0.0, 1.0],
        r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p: [focal, 0.0, cx, 0.0, 0.0, focal, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        ..CameraInfo::default()
    }
}

#[derive(Default)]
struct Tap {
    /// The calibration of the images now (sent when it changes).
    current: Option<CameraInfo>,
    /// Not yet read by the in-process estimator.
    unread: Option<(CameraInfo, u64)>,
    outputs: Publishers<CameraInfo>,
}

/// Where an image source's assumed calibration goes; see the module docs. Cloned
/// handles share it.
#[derive(Clone, Default)]
pub struct CameraTap(Arc<Mutex<Tap>>);

impl CameraTap {
    fn lock(&self) -> std::sync::MutexGuard<'_, Tap> {
        // A panic elsewhere while holding it leaves a calibration, still usable.
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The calibration of the next image: published and kept when it differs from the
    /// one before (the stamp apart).
    pub fn image(&self, info: CameraInfo, stamp_ns: u64) {
        let mut tap = self.lock();
        let same = tap.current.as_ref().is_some_and(|c| {
            (c.width, c.height, c.k, &c.header.frame_id)
                == (info.width, info.height, info.k, &info.header.frame_id)
        });
        if same {
            return;
        }
        tap.outputs.publish(&info, stamp_ns);
        tap.unread = Some((info.clone(), stamp_ns));
        tap.current = Some(info);
    }

    /// Also publishes the calibrations to `outputs` from now on (and the current one at
    /// once).
    pub fn publish_to(&self, outputs: Publishers<CameraInfo>) {
        let mut tap = self.lock();
        tap.outputs = outputs;
        if let Some(info) = tap.current.clone() {
            let stamp = u64::try_from(info.header.stamp.nanos()).unwrap_or(0);
            tap.outputs.publish(&info, stamp);
        }
    }

    /// Flushes and drops the outputs (at the end of a run: before the middleware and the
    /// recording under them), whatever other handles remain.
    pub fn close(&self) {
        let mut outputs = std::mem::take(&mut self.lock().outputs);
        outputs.flush();
    }

    /// The calibrations as a source, each once (for the estimator in the same process).
    pub fn reader(&self) -> Box<dyn Source<CameraInfo>> {
        Box::new(self.clone())
    }
}

impl Source<CameraInfo> for CameraTap {
    fn recv(&mut self, _timeout: Duration) -> Result<Received<CameraInfo>, TransportError> {
        Ok(match self.lock().unread.take() {
            Some((info, stamp)) => Received::Message(info, stamp),
            None => Received::Idle,
        })
    }
}
