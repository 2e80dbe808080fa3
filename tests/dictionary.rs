//! Loading the authors' dictionaries and posestream's own format.

mod common;

use common::shared;
use posestream::LoadDictionary;
use posestream::dictionary::json;
use posestream::{Dictionary, DictionaryError};

#[test]
fn loads_the_authors_dictionaries() {
    let dir = shared().join("reference/monocap-dicts");
    for (file, k, p) in [
        ("poseDict-all-K128.mat", 128, 17),
        ("poseDict-Posing-K64.mat", 64, 17),
        ("tennis_forehand.mat", 64, 15),
    ] {
        let d = Dictionary::load(dir.join(file)).expect(file);
        assert_eq!((d.num_bases(), d.num_joints()), (k, p), "{file}");
        let skel = d.skeleton();
        assert_eq!(skel.joints[0], "root");
        assert_eq!(skel.parents.iter().filter(|q| q.is_none()).count(), 1);
        assert_eq!(skel.torso.first(), Some(&0));
        assert!(!skel.left_right_pairs().is_empty(), "{file}");
        // Bases are centred over the joints.
        for b in d.bases().chunks_exact(p) {
            assert!(b.iter().sum::<f64>().abs() < 1e-9);
        }
    }
}

#[test]
fn the_json_format_round_trips() {
    let d = Dictionary::load(shared().join("reference/monocap-dicts/tennis_forehand.mat"))
        .expect("load");
    let tmp = tempfile::tempdir().expect("tempdir");
    let path = tmp.path().join("d.json");
    json::save(&d, &path, Some("test".into()), None).expect("save");
    let e = Dictionary::load(&path).expect("reload");
    assert_eq!(d, e);
}

#[test]
fn bad_dictionaries_give_clear_errors() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let truncated = tmp.path().join("t.mat");
    let bytes = std::fs::read(shared().join("reference/monocap-dicts/poseDict-all-K128.mat"))
        .expect("read");
    std::fs::write(&truncated, &bytes[..300]).expect("write");
    assert!(matches!(
        Dictionary::load(&truncated),
        Err(DictionaryError::Mat { .. })
    ));
    let bad_json = tmp.path().join("b.json");
    std::fs::write(&bad_json, b"{\"format\": 1}").expect("write");
    assert!(matches!(
        Dictionary::load(&bad_json),
        Err(DictionaryError::Json { .. })
    ));
    assert!(matches!(
        Dictionary::load(tmp.path().join("none.mat")),
        Err(DictionaryError::Io { .. })
    ));
    assert!(matches!(
        Dictionary::load(tmp.path().join("x.txt")),
        Err(DictionaryError::UnknownFormat { .. })
    ));
}
