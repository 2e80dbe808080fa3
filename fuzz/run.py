#!/usr/bin/env python3
"""Runs posestream's fuzz targets (coverage-guided, libFuzzer through cargo-fuzz).

    python3 fuzz/run.py [--seconds N] [--quiet M] [--jobs J] [TARGET ...]
    python3 fuzz/run.py --cmin [TARGET ...]

Builds every target once (`cargo fuzz build`, stable toolchain with RUSTC_BOOTSTRAP=1,
no sanitizer: the sanitizer runtimes are nightly-only), then runs each target (all of
them by default) on its corpus in `fuzz/corpus/<target>` for at most N seconds of CPU
time (default 60), or, with --quiet M, until its coverage (libFuzzer's `cov`, the
code edges reached) has not grown for M seconds of CPU time (at most N: --seconds caps
each run also with --quiet). New corpus entries for new hit counts of edges already
reached (libFuzzer's `ft` features) do not end a quiet spell; the line printed says
when the last of those came too. Both spans are the fuzzer's own CPU time, sampled
every 2 s, so a busy machine neither shortens a quiet spell nor a run. Every 5 minutes
a line says how each running target stands.
J targets run at once (default 1); each prints its line when it ends. New corpus entries are written back to the corpus
folder (`--cmin` keeps it small); a failing input lands in
`fuzz/artifacts/<target>/`: copy it to `fuzz/regressions/<target>/` once fixed, and
`tests/fuzz_corpora.rs` replays it in every CI run.

Prints one line per target: CPU seconds, executions, coverage (libFuzzer's `cov`
counter), corpus size, and whether it failed. Exit status 1 if any target failed.
Needs `cargo install cargo-fuzz`.
"""

import argparse
import concurrent.futures
import hashlib
import os
import re
import signal
import subprocess
import threading
import sys
import time
from pathlib import Path

FUZZ = Path(__file__).resolve().parent
TARGETS = sorted(p.stem for p in (FUZZ / "fuzz_targets").glob("*.rs"))


def build():
    env = dict(os.environ, RUSTC_BOOTSTRAP="1")
    subprocess.run(
        ["cargo", "fuzz", "build", "--sanitizer", "none", "--release", "--debug-assertions"],
        cwd=FUZZ.parent,
        env=env,
        check=True,
    )
    triple = subprocess.run(
        ["rustc", "-vV"], capture_output=True, text=True, check=True
    ).stdout
    host = re.search(r"host: (\S+)", triple).group(1)
    return FUZZ / "target" / host / "release"


def cmin(target):
    """Shrinks a target's corpus (`cargo fuzz cmin`: the smallest inputs that keep its
    coverage, renamed to their SHA-1), then brings back its committed `seed-*` files
    under their own names instead of their hash names."""
    env = dict(os.environ, RUSTC_BOOTSTRAP="1")
    subprocess.run(
        ["cargo", "fuzz", "cmin", "--sanitizer", "none", "--release", "--debug-assertions", target],
        cwd=FUZZ.parent,
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    corpus = FUZZ / "corpus" / target
    seeds = subprocess.run(
        ["git", "ls-files", "--", f"corpus/{target}/seed-*"],
        cwd=FUZZ, capture_output=True, text=True, check=True,
    ).stdout.split()
    if seeds:
        subprocess.run(["git", "checkout", "--", *seeds], cwd=FUZZ, check=True)
    for seed in seeds:
        digest = hashlib.sha1((FUZZ / seed).read_bytes()).hexdigest()
        (corpus / digest).unlink(missing_ok=True)
    return len(list(corpus.iterdir()))


def cpu_seconds(pid):
    """CPU time (user + system) the process has used so far, from /proc."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run(binary, target, seconds, quiet):
    """Runs one target until it has used `seconds` of CPU time or, with `quiet`, until
    it has used `quiet` CPU seconds since its last new corpus entry. Both spans count the
    fuzzer's CPU time, not wall time, so that other work on the machine (a build, a
    second target) can neither shorten a quiet spell nor eat into a run's budget."""
    corpus = FUZZ / "corpus" / target
    artifacts = FUZZ / "artifacts" / target
    corpus.mkdir(parents=True, exist_ok=True)
    artifacts.mkdir(parents=True, exist_ok=True)
    args = [
        str(binary / target),
        str(corpus),
        f"-artifact_prefix={artifacts}/",
        # Allocations beyond the service's limits show up as an RSS far above them.
        "-rss_limit_mb=1024",
        "-timeout=20",
        "-max_len=1048576",
        "-print_final_stats=1",
    ]
    start = time.time()
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    state = {
        "last_new_cpu": 0.0,
        "last_cov_cpu": 0.0,
        "cov": None,
        "cpu": 0.0,
        "stats": {},
        "failed": False,
        "log": [],
    }
    lock = threading.Lock()

    def read():
        for line in proc.stderr:
            cpu = cpu_seconds(proc.pid)
            with lock:
                state["log"].append(line)
                if len(state["log"]) > 200:
                    state["log"].pop(0)
                # The quiet spell starts once the corpus is loaded (INITED), then at
                # every growth of the coverage; new corpus entries are noted too.
                inited = re.search(r"\sINITED\s", line)
                if (inited or re.search(r"\sNEW\s", line)) and cpu is not None:
                    state["last_new_cpu"] = cpu
                m = re.search(r"#(\d+)\s+\S+\s+cov: (\d+).*corp: (\d+)", line)
                if m:
                    cov = int(m.group(2))
                    grew = state["cov"] is not None and cov > state["cov"]
                    if (inited or grew) and cpu is not None:
                        state["last_cov_cpu"] = cpu
                    state["cov"] = cov if state["cov"] is None else max(cov, state["cov"])
                    state["stats"].update(
                        execs=int(m.group(1)), cov=int(m.group(2)), corpus=int(m.group(3))
                    )
                if "ERROR: libFuzzer" in line or "panicked at" in line or "deadly signal" in line:
                    state["failed"] = True

    reader = threading.Thread(target=read, name=f"fuzz-{target}")
    reader.start()
    stopped = None
    last_status = time.time()
    while proc.poll() is None:
        time.sleep(2)
        cpu = cpu_seconds(proc.pid)
        if cpu is None or stopped:
            continue
        with lock:
            state["cpu"] = cpu
            if time.time() - last_status >= 300:
                last_status = time.time()
                print(
                    f"  {target}: cpu {cpu:.0f} s, cov {state['cov']}, no new coverage for "
                    f"{cpu - state['last_cov_cpu']:.0f} CPU s, no new entry for "
                    f"{cpu - state['last_new_cpu']:.0f}",
                    flush=True,
                )
            if quiet is not None and cpu - state["last_cov_cpu"] > quiet:
                stopped = "quiet"
            elif cpu > seconds:
                stopped = "time cap"
        if stopped:
            proc.send_signal(signal.SIGINT)
    reader.join()
    returncode = proc.returncode
    stats = state["stats"]
    stats["cpu_s"] = round(state["cpu"], 1)
    stats["wall_s"] = round(time.time() - start, 1)
    stats["quiet_s"] = round(stats["cpu_s"] - state["last_cov_cpu"], 1)
    stats["entry_s"] = round(stats["cpu_s"] - state["last_new_cpu"], 1)
    # libFuzzer exits with 72 when interrupted (our stop after a quiet spell or at the cap).
    failed = state["failed"] or not (returncode == 0 or stopped and returncode in (72, -2, -15))
    stats["stopped"] = stopped or "exited"
    return target, stats, failed, "".join(state["log"][-40:]) if failed else ""


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=int, default=60)
    p.add_argument("--quiet", type=int, default=None)
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument(
        "--cmin", action="store_true",
        help="shrink the corpora instead of fuzzing (keeps the seed-* files)",
    )
    p.add_argument("targets", nargs="*", default=TARGETS)
    a = p.parse_args()
    unknown = set(a.targets) - set(TARGETS)
    if unknown:
        sys.exit(f"unknown targets {sorted(unknown)}; known: {TARGETS}")
    binary = build()
    if a.cmin:
        for target in a.targets:
            print(f"{target:14} corpus {cmin(target)} files", flush=True)
        return
    any_failed = False
    with concurrent.futures.ThreadPoolExecutor(a.jobs) as pool:
        # Each result is printed as its target ends, so that a campaign stopped
        # half-way keeps the lines of the targets that finished.
        runs = [pool.submit(run, binary, t, a.seconds, a.quiet) for t in a.targets]
        for done in concurrent.futures.as_completed(runs):
            target, stats, failed, log = done.result()
            any_failed |= failed
            print(
                f"{target:14} {'FAILED' if failed else 'ok':6} cpu {stats.get('cpu_s')} s, "
                f"wall {stats.get('wall_s')} s, {stats.get('execs', 0)} runs, "
                f"cov {stats.get('cov', 0)}, corpus {stats.get('corpus', 0)}, "
                f"last new coverage {stats.get('quiet_s')} CPU s before the end, last new "
                f"corpus entry {stats.get('entry_s')} ({stats.get('stopped')})",
                flush=True,
            )
            if log:
                print(log, flush=True)
    sys.exit(1 if any_failed else 0)


if __name__ == "__main__":
    main()
