//! `posestream render`: pictures of a run (a recording written by `posestream run` on
//! images) next to its camera images: a PNG of one frame, or a GIF of all of them.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use clap::Args;
use image::codecs::gif::{GifEncoder, Repeat};
use image::{Delay, Frame};
use posestream::files::OutputFile;
use posestream::msgs::{HeatMaps, Skeleton3D};
use posestream::nodes::config::DetectorSource;
use posestream::nodes::images::image_frames;
use posestream::recording::{read_topic, salvage_topic};
use posestream::render::{Person, RenderSettings, render_frame};
use posestream::transport::{Received, Source, TransportError};

use super::CliError;

/// Options of `render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// The recording of the run (skeletons, and heat maps for the overlay).
    pub recording: PathBuf,
    /// The picture: `.png` (one frame) or `.gif` (every frame with a skeleton).
    #[arg(long, short)]
    pub output: PathBuf,
    /// The run's images: a folder (overrides `[detector.images]`).
    #[arg(long, group = "frames")]
    pub images: Option<PathBuf>,
    /// The run's images: a video file.
    #[arg(long, group = "frames")]
    pub video: Option<PathBuf>,
    /// The service configuration (`--config FILE`).
    #[command(flatten)]
    pub config: super::config::ConfigArgs,
    /// The frame of a PNG (sequence number; default: the middle frame with a skeleton).
    #[arg(long)]
    pub frame: Option<u64>,
    /// The first frame of a GIF (sequence number).
    #[arg(long)]
    pub from: Option<u64>,
    /// The last frame of a GIF (sequence number).
    #[arg(long)]
    pub to: Option<u64>,
    /// Draw the newest estimate of each frame, not the refined (lagged) one.
    #[arg(long)]
    pub newest: bool,
    /// Picture height, pixels (16 to 4096).
    #[arg(long, default_value_t = 360, value_parser = clap::value_parser!(u32).range(16..=4096))]
    pub height: u32,
    /// Stop at the recording's first damaged part, with an error (default: skip what
    /// cannot be read and draw the rest; sets `replay.strict`).
    #[arg(long)]
    pub strict: bool,
    /// The 3D view's azimuth, degrees.
    #[arg(long, default_value_t = 60.0, allow_negative_numbers = true)]
    pub azimuth: f64,
}

/// The messages of `topic` in `recording`: every readable one, what was skipped said in
/// a warning (strict: up to the first damage, an error).
fn read<M: posestream::msgs::RosMessage>(
    recording: &std::path::Path,
    topic: &str,
    config: &posestream::nodes::ServiceConfig,
) -> Result<Vec<(u64, M)>, posestream::recording::RecordingError> {
    if config.replay.strict {
        return read_topic::<M>(recording, topic);
    }
    let (messages, skipped) = salvage_topic::<M>(recording, topic, config.limits.max_record_bytes)?;
    if !skipped.is_empty() {
        eprintln!(
            "posestream: warning: {} ({topic}): damaged parts skipped, every readable message \
             used: {} (--strict stops at the first)",
            recording.display(),
            skipped.summary()
        );
    }
    Ok(messages)
}

/// Runs `render`.
pub fn run(args: &RenderArgs) -> Result<(), CliError> {
    let mut config = args.config.load()?;
    config.replay.strict |= args.strict;
    if let Some(p) = &args.images {
        config.detector.source = DetectorSource::Images;
        config.detector.images.path = p.clone();
    }
    if let Some(p) = &args.video {
        config.detector.source = DetectorSource::Video;
        config.detector.images.path = p.clone();
    }
    if matches!(
        config.detector.source,
        DetectorSource::Recording | DetectorSource::Ros2
    ) {
        return Err(CliError::Usage(
            "render needs the run's images: --images DIR, --video FILE, or an image source in [detector]"
                .into(),
        ));
    }
    let gif = match args.output.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case("gif") => true,
        Some(e) if e.eq_ignore_ascii_case("png") => false,
        _ => return Err(CliError::Usage("--output must end in .png or .gif".into())),
    };
    // The picture is written under a temporary name and renamed at the end; never onto
    // the recording, the video, one of the images or the configuration.
    let mut inputs = vec![args.recording.clone(), config.detector.images.path.clone()];
    if config.detector.source == DetectorSource::Images
        && let Ok(entries) = std::fs::read_dir(&config.detector.images.path)
    {
        inputs.extend(entries.flatten().map(|e| e.path()));
    }
    inputs.extend(args.config.config.clone());
    let inputs: Vec<&std::path::Path> = inputs.iter().map(PathBuf::as_path).collect();
    let mut output = OutputFile::create(&args.output, &inputs)?;
    let dictionary = posestream::msgs::shipped::load_dictionary(&config.estimator.dictionary)?;
    let bones: Vec<(usize, usize)> = dictionary.skeleton().bones().collect();
    // Per frame and person, the estimate to draw: the most refined one unless --newest.
    let mut skeletons: BTreeMap<u64, BTreeMap<u32, Skeleton3D>> = BTreeMap::new();
    let recorded = read::<Skeleton3D>(&args.recording, &config.topics.skeletons, &config)?;
    for (_, s) in recorded {
        let in_range =
            args.from.is_none_or(|f| s.sequence >= f) && args.to.is_none_or(|t| s.sequence <= t);
        if gif && !in_range {
            continue;
        }
        let people = skeletons.entry(s.sequence).or_default();
        let keep = match people.get(&s.track_id) {
            None => true,
            Some(old) if args.newest => s.lag < old.lag,
            Some(old) => s.lag > old.lag,
        };
        if keep {
            people.insert(s.track_id, s);
        }
    }
    if skeletons.is_empty() {
        return Err(CliError::Nothing(format!(
            "{}: no skeletons on {} (in the frames asked for)",
            args.recording.display(),
            config.topics.skeletons
        )));
    }
    let maps: BTreeMap<(u64, u32), HeatMaps> =
        match read::<HeatMaps>(&args.recording, &config.topics.heatmaps, &config) {
            Ok(all) => all
                .into_iter()
                .map(|(_, m)| ((m.sequence, m.track_id), m))
                .collect(),
            Err(e) => {
                tracing::warn!("no heat-map overlay: {e}");
                BTreeMap::new()
            }
        };
    let wanted = args.frame.unwrap_or_else(|| {
        let keys: Vec<u64> = skeletons.keys().copied().collect();
        keys[keys.len() / 2]
    });
    if !gif && !skeletons.contains_key(&wanted) {
        return Err(CliError::Nothing(format!(
            "frame {wanted} has no skeleton in the recording"
        )));
    }
    let settings = RenderSettings {
        height: args.height,
        azimuth_deg: args.azimuth,
        ..RenderSettings::default()
    };
    let mut frames = image_frames(&config, None)?;
    let progress = indicatif::ProgressBar::new(skeletons.len() as u64);
    let mut pictures = Vec::new();
    let mut stamps = Vec::new();
    loop {
        let frame = match frames.recv(Duration::from_millis(100)) {
            Ok(Received::Message(f, _)) => f,
            Ok(Received::Idle) => continue,
            Ok(Received::Closed) => break,
            Err(e @ TransportError::Malformed { .. }) => {
                tracing::warn!("{e}");
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let Some(people) = skeletons.get(&frame.sequence) else {
            continue;
        };
        if !gif && frame.sequence != wanted {
            continue;
        }
        let people: Vec<Person<'_>> = people
            .values()
            .map(|skeleton| Person {
                maps: maps.get(&(frame.sequence, skeleton.track_id)),
                skeleton,
            })
            .collect();
        let picture = render_frame(&frame.rgb, &people, &bones, &settings);
        progress.inc(1);
        stamps.push(frame.stamp_ns);
        pictures.push(picture);
        if !gif {
            break;
        }
    }
    progress.finish_and_clear();
    if pictures.is_empty() {
        return Err(CliError::Nothing(
            "none of the images has a skeleton in the recording (another run?)".into(),
        ));
    }
    let picture_error = |source| CliError::Picture {
        path: args.output.clone(),
        source,
    };
    if gif {
        let mut encoder = GifEncoder::new_with_speed(output.writer(), 10);
        encoder
            .set_repeat(Repeat::Infinite)
            .map_err(picture_error)?;
        for (i, picture) in pictures.into_iter().enumerate() {
            let ms = match (stamps.get(i), stamps.get(i + 1)) {
                (Some(a), Some(b)) if b > a => ((b - a) / 1_000_000).clamp(20, 2000),
                _ => 100,
            };
            let rgba = image::DynamicImage::ImageRgb8(picture).to_rgba8();
            let delay = Delay::from_saturating_duration(Duration::from_millis(ms));
            encoder
                .encode_frame(Frame::from_parts(rgba, 0, 0, delay))
                .map_err(picture_error)?;
        }
        drop(encoder);
        output.commit()?;
        println!("{} frames -> {}", stamps.len(), args.output.display());
    } else {
        pictures[0]
            .write_to(output.writer(), image::ImageFormat::Png)
            .map_err(picture_error)?;
        output.commit()?;
        println!("frame {wanted} -> {}", args.output.display());
    }
    Ok(())
}
