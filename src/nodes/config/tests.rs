//! Unit tests of `config`.

use super::*;

/// `config/default.toml` lists every key with its default value.
#[test]
fn the_shipped_configuration_is_the_default_one_and_lists_every_key() {
    let text = include_str!("../../../config/default.toml");
    let parsed: ServiceConfig = toml::from_str(text).expect("parses");
    assert_eq!(parsed, ServiceConfig::default());
    // Every key of the default, serialised, appears in the file.
    let full = toml::to_string(&ServiceConfig::default()).expect("serialises");
    let mut section = String::new();
    for line in full.lines() {
        if line.starts_with('[') {
            section = line.to_string();
            assert!(text.contains(line), "section {line} missing");
        } else if let Some((key, _)) = line.split_once(" = ") {
            let listed = text
                .lines()
                .any(|l| l.trim_start().starts_with(&format!("{key} = ")));
            // `init` is optional (None): listed commented out.
            assert!(listed || key == "init", "{section} {key} missing");
        }
    }
}

#[test]
fn the_annotated_configuration_says_where_each_value_came_from_and_reads_back() {
    let text = "[detector.images]\npath = \"a\\nb\\n[topics]\\nheatmaps = 1\"\n\
                [estimator.window]\nlag = 5\n";
    let path = Path::new("mine.toml");
    let config = ServiceConfig::parse(text, path).expect("parses");
    let file: toml::Table = toml::from_str(text).expect("table");
    let out = config.annotated(Some((path, &file))).expect("writes");
    let line = |key: &str| {
        out.lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .unwrap_or_else(|| panic!("{key}: {out}"))
    };
    assert!(line("lag").ends_with("# mine.toml"), "{out}");
    assert!(line("size").ends_with("# default"), "{out}");
    assert!(line("path").ends_with("# mine.toml"), "{out}");
    // A value holding newlines stays on its line; the whole reads back as it was.
    assert!(!out.lines().any(|l| l.starts_with("heatmaps = 1")), "{out}");
    assert!(line("path").contains("\\n[topics]\\nheatmaps = 1"), "{out}");
    let back = ServiceConfig::parse(&out, path).expect("reads back");
    assert_eq!(back, config);
    assert_eq!(
        ServiceConfig::parse(&ServiceConfig::default().annotated(None).expect("w"), path)
            .expect("reads back"),
        ServiceConfig::default()
    );
}

#[test]
fn a_section_written_as_an_array_or_a_value_is_said_so() {
    for (bad, says) in [
        (
            "[[detector]]\nsource = \"video\"\n",
            "[detector] must be a section",
        ),
        ("estimator = [1, 2]\n", "[estimator] must be a section"),
        (
            "[estimator]\nwindow = 3\n",
            "[estimator.window] must be a section",
        ),
    ] {
        let e = ServiceConfig::parse(bad, Path::new("c.toml")).expect_err(bad);
        assert!(e.to_string().contains(says), "{bad}: {e}");
    }
}

#[test]
fn unknown_keys_and_bad_values_are_errors() {
    for bad in [
        "[ros.qos]\nreliabilty = \"reliable\"\n",
        "[ros.qos]\nreliability = \"sometimes\"\n",
        "[outputs]\nshm = true\n",
        "[iceoryx2]\nskeleton = \"x\"\n",
        "[detector]\nrate = \"slow\"\n",
        "[detector]\nsource = \"webcam\"\n",
        "[detector.images]\nmodel = \"huge\"\n",
        "[detector.images]\nperson = [1, 2, 3, 4]\n",
        "[estimator]\ninput = \"zenoh\"\n",
        "[estimator.params]\nstart_from_window = \"yes\"\n",
        "[estimator.params]\nstart_from_window = 1\n",
        "[estimator.params]\nstart_from_windows = false\n",
    ] {
        assert!(toml::from_str::<ServiceConfig>(bad).is_err(), "{bad}");
    }
}
