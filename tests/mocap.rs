//! Motion capture: the shipped mappings on real files, `learn-dict` and `synth` from the
//! command line, and one clear error for bad BVH or mapping files.

mod common;

use posestream::LoadDictionary;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::shared;
use posestream::Dictionary;
use posestream::mocap::{Bvh, SkeletonMapping};
use posestream::npy::{self, Array};

fn posestream(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_posestream"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run posestream")
}

fn mocap(name: &str) -> PathBuf {
    let set = if name.starts_with("dataset-1") {
        "bandai-namco-1"
    } else {
        "bandai-namco-2"
    };
    shared()
        .join("data/mocap")
        .join(set)
        .join(format!("{name}.bvh"))
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// A CMU-style BVH (cgspeed names, End Site on the head), standing still for 3 frames.
const CMU: &str = "HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT LeftUpLeg { OFFSET 1.6 -1.8 0 CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT LeftLeg { OFFSET 0 -7.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT LeftFoot { OFFSET 0 -7.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
        End Site { OFFSET 0 0 2 } } } }
  JOINT RightUpLeg { OFFSET -1.6 -1.8 0 CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT RightLeg { OFFSET 0 -7.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT RightFoot { OFFSET 0 -7.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
        End Site { OFFSET 0 0 2 } } } }
  JOINT Spine { OFFSET 0 2 0 CHANNELS 3 Zrotation Yrotation Xrotation
    JOINT Neck { OFFSET 0 8 0 CHANNELS 3 Zrotation Yrotation Xrotation
      JOINT Head { OFFSET 0 1.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
        End Site { OFFSET 0 3.5 0 } }
      JOINT LeftArm { OFFSET 3 -0.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT LeftForeArm { OFFSET 5 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
          JOINT LeftHand { OFFSET 4.5 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
            End Site { OFFSET 1 0 0 } } } }
      JOINT RightArm { OFFSET -3 -0.5 0 CHANNELS 3 Zrotation Yrotation Xrotation
        JOINT RightForeArm { OFFSET -5 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
          JOINT RightHand { OFFSET -4.5 0 0 CHANNELS 3 Zrotation Yrotation Xrotation
            End Site { OFFSET -1 0 0 } } } } } }
}
MOTION
Frames: 3
Frame Time: 0.0083333
";

fn cmu_text() -> String {
    let channels = 6 + 3 * 15;
    let row = vec!["0"; channels].join(" ");
    format!("{CMU}{row}\n{row}\n{row}\n")
}

#[test]
fn the_shipped_mappings_fit_their_skeletons() {
    // Bandai-Namco: a real file; plausible human proportions in metres, z up.
    let m = SkeletonMapping::load(repo("config/skeletons/bandai-namco.toml")).expect("mapping");
    let file = mocap("dataset-1_walk_normal_001");
    let bvh = Bvh::load(&file).expect("bvh");
    let seq = m.apply(&bvh, "walk").expect("applies");
    assert_eq!((seq.joints, seq.frames), (17, bvh.frames()));
    let at = |name: &str| {
        let j = m.layout.index_of(name).expect("joint");
        seq.positions[3 * j + 2]
    };
    assert!(
        at("head-top") > 1.4 && at("head-top") < 2.0,
        "{}",
        at("head-top")
    );
    assert!(at("l-ankle") < 0.3 && at("pelvis") > 0.7 && at("pelvis") < 1.1);
    // CMU: names resolved through alternatives, head-top from the head's End Site.
    let m = SkeletonMapping::load(repo("config/skeletons/cmu.toml")).expect("mapping");
    let bvh = Bvh::parse(&cmu_text()).expect("cmu bvh");
    let seq = m.apply(&bvh, "cmu").expect("applies");
    let top = m.layout.index_of("head-top").expect("joint");
    let neck = m.layout.index_of("neck").expect("joint");
    let up = seq.positions[3 * top + 2] - seq.positions[3 * neck + 2];
    assert!((up - 3.5 * m.metres_per_unit).abs() < 1e-9, "{up}");
}

#[test]
fn learn_dict_writes_a_dictionary_in_the_layout() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let out = tmp.path().join("d.json");
    let o = posestream(&[
        "learn-dict",
        "--mapping",
        "config/skeletons/bandai-namco.toml",
        "--data",
        &mocap("dataset-1_bow_normal_001").to_string_lossy(),
        &mocap("dataset-2_walk_normal_001").to_string_lossy(),
        "--atoms",
        "16",
        "--iterations",
        "20",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("mean active atoms"), "{text}");
    let d = Dictionary::load(&out).expect("loads");
    assert_eq!((d.num_bases(), d.num_joints()), (16, 17));
    assert_eq!(d.skeleton().joints[10], "head-top");
}

#[test]
fn the_shipped_dictionary_is_in_the_default_layout() {
    let d = Dictionary::load(repo("config/dictionaries/default-k128.json")).expect("loads");
    assert_eq!((d.num_bases(), d.num_joints()), (128, 17));
    assert!(posestream::skeleton::is_default_layout(
        &d.skeleton().joints
    ));
}

#[test]
fn synth_writes_what_lift_reads() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("seq");
    let o = posestream(&[
        "synth",
        "--bvh",
        &mocap("dataset-1_kick_normal_001").to_string_lossy(),
        "--mapping",
        "config/skeletons/bandai-namco.toml",
        "--frames",
        "40",
        "--orbit",
        "15",
        "--swap-rate",
        "0.05",
        "--out",
        &dir.to_string_lossy(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let shape = |name: &str| {
        if name == "heatmaps.npy" {
            npy::read::<f32>(&dir.join(name)).expect(name).shape
        } else {
            npy::read::<f64>(&dir.join(name)).expect(name).shape
        }
    };
    assert_eq!(shape("gt_3d.npy"), vec![40, 17, 3]);
    assert_eq!(shape("keypoints.npy"), vec![40, 17, 2]);
    assert_eq!(shape("boxes.npy"), vec![40, 4]);
    assert_eq!(shape("heatmaps.npy"), vec![40, 17, 64, 64]);
    assert_eq!(shape("gt_2d_heatmap.npy"), vec![40, 17, 2]);
    let path = |n: &str| dir.join(n).to_string_lossy().into_owned();
    // The metric scale is an input of the perspective step: the subject's own mean bone
    // length over the layout's tree.
    let truth: Array<f64> = npy::read(&dir.join("gt_3d.npy")).expect("truth");
    let layout = posestream::skeleton::default_layout();
    let bones: Vec<f64> = layout
        .bones()
        .map(|(a, b)| {
            (0..3)
                .map(|i| (truth.data[3 * a + i] - truth.data[3 * b + i]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    let limb = format!("{}", bones.iter().sum::<f64>() / bones.len() as f64);
    let o = posestream(&[
        "lift",
        "--mean-limb-length",
        &limb,
        "--dict",
        "config/dictionaries/default-k128.json",
        "--heatmaps",
        &path("heatmaps.npy"),
        "--intrinsics",
        &path("intrinsics.json"),
        "--boxes",
        &path("boxes.npy"),
        "--out",
        &path("pred.npy"),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Metric poses near the truth: root-aligned error under 15 cm.
    let pred: Array<f64> = npy::read(&dir.join("pred.npy")).expect("pred");
    let e = posestream::accuracy::root_aligned_mpjpe(&pred.data, &truth.data, 17, 0);
    assert!(e < 0.15, "root-aligned MPJPE {e} m");
}

#[test]
fn bad_bvh_and_mapping_files_give_one_clear_error() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let write = |name: &str, text: &str| {
        let p = tmp.path().join(name);
        std::fs::write(&p, text).expect("write");
        p.to_string_lossy().into_owned()
    };
    let good_bvh = mocap("dataset-1_bow_normal_001")
        .to_string_lossy()
        .into_owned();
    let real = std::fs::read_to_string(&good_bvh).expect("read");
    let truncated = write("truncated.bvh", &real[..real.len() - 200]);
    let bad_channel = write("channel.bvh", &real.replacen("Zrotation", "Qrotation", 1));
    let cmu = write("cmu.bvh", &cmu_text());
    let mapping =
        std::fs::read_to_string(repo("config/skeletons/bandai-namco.toml")).expect("read");
    let unknown_joint = write("unknown.toml", &mapping.replace("\"Foot_L\"", "\"Fot_L\""));
    let unmapped = write(
        "unmapped.toml",
        &mapping.replace("r-wrist = { joint = \"Hand_R\" }", ""),
    );
    let extra_key = write("extra.toml", &format!("colour = 1\n{mapping}"));
    let not_layout = write(
        "layout.toml",
        &format!("{mapping}\nnose = {{ joint = \"Head\" }}\n"),
    );
    let two_kinds = write(
        "kinds.toml",
        &mapping.replace(
            "{ joint = \"Hand_R\" }",
            "{ joint = \"Hand_R\", mean = [\"Hand_L\"] }",
        ),
    );
    let shipped = "config/skeletons/bandai-namco.toml";
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec![&truncated, shipped], "truncated"),
        (vec![&bad_channel, shipped], "unknown channel `Qrotation`"),
        (vec!["/nonexistent.bvh", shipped], "cannot read"),
        (vec![&cmu, shipped], "needs BVH joint `UpperLeg_L`"),
        (vec![&good_bvh, &unknown_joint], "`Fot_L`"),
        (vec![&good_bvh, &unmapped], "`r-wrist` is not mapped"),
        (vec![&good_bvh, &extra_key], "colour"),
        (
            vec![&good_bvh, &not_layout],
            "`nose` is not a joint of the layout",
        ),
        (vec![&good_bvh, &two_kinds], "exactly one of"),
    ];
    for (files, needle) in cases {
        let out = tmp.path().join("out").to_string_lossy().into_owned();
        let o = posestream(&[
            "synth",
            "--bvh",
            files[0],
            "--mapping",
            files[1],
            "--out",
            &out,
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{needle}: succeeded");
        assert!(err.contains(needle), "{needle}: `{err}`");
        assert!(!err.contains("panicked"), "{err}");
        assert_eq!(err.matches("error:").count(), 1, "{needle}: `{err}`");
    }
}
