#![no_main]
//! `posestream_fuzz::live_view` under libFuzzer.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    posestream_fuzz::panics_abort_unless_contained();
    posestream_fuzz::live_view(data)
});
