"""Tap history at farm scale: the store's size per tap, the ingest rate with 50 printers
tapping at once, and the fleet page's latency with 50 printers and 500,000 taps in PostgreSQL.

    python -m bench history [--printers 50] [--taps-per-printer 10000] [--ingest-taps 20]

Everything runs on a throw-away PostgreSQL (Debian's, bench/_postgres.py) and a temp SQLite
file. Real taps: synthetic taps (tapcell.tap.synth, 660 samples/s) analysed by tapcell, stored
as the monitor stores them (samples, moves, both results; no Z per sample, which a printer's
dump_taps event does not carry). Scale fill: 500,000 rows written with COPY, whose health columns are drawn per
printer (noise, stiffness, Z at a grid of spots, ~3 % rejected) and whose stored document is a
short stand-in: PostgreSQL keeps large documents out of line (TOAST), and the fleet page reads
only the health columns of each printer's latest 250 taps, so the stand-in changes the disk
size, not what the page reads. Three printers get a real change in their latest 50 taps
(noise × 1.5) so that the trend flag has something to find.

Anchors measured in the same run: the analysis of one tap (what a monitor spends anyway per
tap), one writer alone (for the 50 writers), the monitor's JSONL log line (for the size), and a
static file from the same server (for the page).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import zlib
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from bench._postgres import Cluster, ClusterUnavailable
from bench._progress import with_progress
from tapcell.store import Store, health
from tapcell.store.records import tap_record
from tapcell.tap import analyze_tap
from tapcell.tap.readers import tap_to_json_dict
from tapcell.tap.synth import synth_tap

GOAL_PAGE_S = 1.0
# A load-cell tap with its moves takes about 1.5-3 s on a printer (approach, dwell, pullback,
# lift, travel); 50 printers probing at once ask for at most ~50 taps/s.
DEMAND_TAPS_S_PER_PRINTER = 1.0
CHANGED_PRINTERS = (3, 17, 41)
PAGE_REPEATS = 10
COPY_COLUMNS = ("printer_id", "tap_key", "recorded_s", "x_mm", "y_mm", "printer_z_mm", "printer_valid",
                "printer_error", "tapcell_z_mm", "tapcell_valid", "tapcell_error", "cause", "quality",
                "stiffness_g_um", "noise_sigma_g", "document")


def real_documents(count: int) -> tuple[list[dict], float]:
    """`count` analysed synthetic taps as the monitor stores them; the analysis time per tap (s)."""
    documents = []
    spent = 0.0
    rng = np.random.default_rng(7)
    for seed in range(count):
        tap = synth_tap(seed=seed, z_contact_mm=float(rng.normal(0.0, 0.05)), noise_g=float(rng.uniform(0.5, 1.5)))
        started = time.perf_counter()
        analysis = analyze_tap(tap)
        spent += time.perf_counter() - started
        document = tap_to_json_dict(tap, analysis)
        document.pop("z")  # a printer's dump_taps event carries the moves, not Z per sample: as a monitor stores it
        x_mm, y_mm = float(rng.uniform(20, 220)), float(rng.uniform(20, 220))
        z_mm = analysis.z_mm if analysis.z_mm is not None else 0.0
        document["printer"] = {"z": z_mm, "tap_pos": [x_mm, y_mm, z_mm], "is_valid": True, "error": None}
        document["meta"]["recorded_s"] = time.time()
        documents.append(document)
    return documents, spent / count


def variant(document: dict, n: int) -> dict:
    """The same tap with one sample nudged: a distinct tap of the same size."""
    copy = dict(document)
    copy["force"] = list(document["force"])
    copy["force"][0] += n * 1e-6
    return copy


def size_per_tap(url: str, documents: list[dict], copies: int) -> float:
    with Store(url) as store:
        store.add_tap("size", variant(documents[0], 0))  # the schema and first pages exist
        before = store.size_bytes()
        batch = [variant(document, n) for n in range(1, copies + 1) for document in documents]
        for start in range(0, len(batch), 200):
            store.add_taps("size", batch[start:start + 200])
        if store.engine.dialect.name == "postgresql":
            with store.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as connection:
                connection.exec_driver_sql("CHECKPOINT")
        else:
            with store.engine.connect() as connection:
                connection.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
        return (store.size_bytes() - before) / len(batch)


def ingest(url: str, documents: list[dict], writers: int, taps_each: int, offset: int) -> float:
    """Taps/s with `writers` printers writing `taps_each` taps at once through one store (one monitor)."""
    with Store(url) as store:
        store.add_printer("warm-up")
        work = [[variant(documents[(w * taps_each + k) % len(documents)], offset + w * taps_each + k)
                 for k in range(taps_each)] for w in range(writers)]
        barrier = threading.Barrier(writers + 1)

        def write(number: int) -> None:
            barrier.wait()
            for document in work[number]:
                store.add_tap(f"ingest-{number:02d}", document)

        threads = [threading.Thread(target=write, args=(n,)) for n in range(writers)]
        for thread in threads:
            thread.start()
        barrier.wait()
        started = time.perf_counter()
        for thread in threads:
            thread.join()
        return writers * taps_each / (time.perf_counter() - started)


def fill(url: str, printers: int, taps_per_printer: int) -> float:
    """Fill the store with COPY; returns seconds spent."""
    rng = np.random.default_rng(11)
    stand_in = zlib.compress(json.dumps({"format": "tapcell.tap.v1", "bench": "stand-in"}).encode())
    spots = [(x, y) for x in np.linspace(20, 220, 7) for y in np.linspace(20, 220, 7)]
    started = time.perf_counter()
    with Store(url) as store:
        ids = [store.add_printer(f"printer-{n:02d}", f"http://printer-{n:02d}.local:7125") for n in range(printers)]
        raw = store.engine.raw_connection()
        try:
            cursor = raw.cursor()
            for number in with_progress(range(printers), printers, "fill (printers)", steps=5):
                noise = rng.uniform(0.6, 1.4)
                stiffness = rng.uniform(3.0, 6.0)
                bed = {spot: rng.normal(0.0, 0.05) for spot in spots}
                with cursor.copy(f"COPY taps ({', '.join(COPY_COLUMNS)}) FROM STDIN") as copy:
                    for k in range(taps_per_printer):
                        changed = number in CHANGED_PRINTERS and k >= taps_per_printer - health.RECENT_TAPS
                        x, y = spots[k % len(spots)]
                        z = bed[(x, y)] + rng.normal(0.0, 0.0015)
                        rejected = rng.random() < 0.03
                        copy.write_row((ids[number], f"{number}-{k}", 1.7e9 + k * 2.0, x, y, z, not rejected,
                                        "TAP_SHAPE_INVALID" if rejected else None, z + rng.normal(0, 0.0005), True,
                                        None, "printer: TAP_SHAPE_INVALID - bench" if rejected else "",
                                        float(rng.uniform(80, 99)), float(rng.normal(stiffness, 0.1)),
                                        float(rng.normal(noise * (1.5 if changed else 1.0), 0.05)), stand_in))
            raw.commit()
            cursor.execute("ANALYZE")
            raw.commit()
        finally:
            raw.close()
    return time.perf_counter() - started


def timed_gets(url: str, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        with urllib.request.urlopen(url, timeout=60) as answer:
            answer.read()
        times.append(time.perf_counter() - started)
    return times


def page_latency(url: str) -> dict[str, list[float]]:
    """Median page times through `tapcell web` (uvicorn) on the store."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    web = subprocess.Popen([sys.executable, "-m", "tapcell", "web", "--db", url, "--port", str(port)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                timed_gets(base + "/static/tapcell.css", 1)
                break
            except OSError:
                if time.monotonic() > deadline or web.poll() is not None:
                    raise RuntimeError(f"tapcell web did not start: {web.stderr.read() if web.poll() is not None else ''}")
                time.sleep(0.2)
        timed_gets(base + "/", 2)  # warm the database's cache, as a page viewed twice
        return {"/": timed_gets(base + "/", PAGE_REPEATS), "/api/fleet": timed_gets(base + "/api/fleet", PAGE_REPEATS),
                "/printer/printer-03": timed_gets(base + "/printer/printer-03", PAGE_REPEATS),
                "/static/tapcell.css": timed_gets(base + "/static/tapcell.css", PAGE_REPEATS)}
    finally:
        web.terminate()
        web.wait(timeout=10)


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench history", description=__doc__.split("\n\n")[0])
    parser.add_argument("--printers", type=int, default=50)
    parser.add_argument("--taps-per-printer", type=int, default=10_000)
    parser.add_argument("--ingest-taps", type=int, default=20, help="taps each printer writes in the ingest run")
    args = parser.parse_args(argv)
    console = Console()
    try:
        cluster = Cluster()
        cluster.start(durable=True)
    except ClusterUnavailable as exc:
        print(f"bench history: PostgreSQL unavailable ({exc}); 'make postgresql' installs it")
        return 1
    folder = Path(tempfile.mkdtemp(prefix="tapcell-bench-history-"))
    try:
        documents, analysis_s = real_documents(40)
        log_bytes = statistics.mean(len(json.dumps(d, allow_nan=False)) + 1 for d in documents)
        record_bytes = statistics.mean(len(tap_record(d, 0.0).document) for d in documents)
        sqlite_url = f"sqlite:///{folder / 'taps.db'}"
        size = Table(title="Store size per tap (40 analysed synthetic taps × 25 variants = 1,000 taps)")
        for column in ("store", "bytes per tap", "× the JSONL log line"):
            size.add_column(column, justify="right")
        size.add_row("JSONL log line (anchor, tapcell monitor --log)", f"{log_bytes:,.0f}", "1.00")
        size.add_row("compressed document alone", f"{record_bytes:,.0f}", f"{record_bytes / log_bytes:.2f}")
        for name, url in (("SQLite", sqlite_url), ("PostgreSQL", cluster.new_database("size"))):
            per_tap = size_per_tap(url, documents, 25)
            size.add_row(name, f"{per_tap:,.0f}", f"{per_tap / log_bytes:.2f}")
        console.print(size)

        demand = args.printers * DEMAND_TAPS_S_PER_PRINTER
        rates = Table(title=f"Ingest: {args.printers} printers writing {args.ingest_taps} taps each at once "
                            "through one store (one monitor process)")
        for column in ("store", "writers", "taps/s", "× one writer", f"× demand ({demand:.0f} taps/s)",
                       "× analysis rate"):
            rates.add_column(column, justify="right")
        analysis_rate = 1.0 / analysis_s
        rates.add_row("analysis alone (anchor, 1 core)", "1", f"{analysis_rate:,.0f}", "", f"{analysis_rate / demand:.1f}",
                      "1.00")
        for name, url in (("SQLite", f"sqlite:///{folder / 'ingest.db'}"), ("PostgreSQL", cluster.new_database("ingest"))):
            one = ingest(url, documents, 1, args.ingest_taps * 5, 0)
            many = ingest(url, documents, args.printers, args.ingest_taps, 10_000)
            rates.add_row(name, "1", f"{one:,.0f}", "1.00", f"{one / demand:.1f}", f"{one / analysis_rate:.2f}")
            rates.add_row(name, str(args.printers), f"{many:,.0f}", f"{many / one:.2f}", f"{many / demand:.1f}",
                          f"{many / analysis_rate:.2f}")
        console.print(rates)

        url = cluster.new_database("fleet")
        total = args.printers * args.taps_per_printer
        fill_s = fill(url, args.printers, args.taps_per_printer)
        with Store(url) as store:
            fleet = store.fleet()
        flagged = {row["name"] for row in fleet if row["flagged"]}
        expected = {f"printer-{n:02d}" for n in CHANGED_PRINTERS if n < args.printers}
        latency = page_latency(url)
        anchor = statistics.median(latency["/static/tapcell.css"])
        page = Table(title=f"Pages: {args.printers} printers, {total:,} taps in PostgreSQL "
                           f"(filled in {fill_s:.0f} s; median of {PAGE_REPEATS} requests)")
        for column in ("request", "median ms", "max ms", "× static file", f"× goal ({GOAL_PAGE_S:g} s)"):
            page.add_column(column, justify="right")
        for path, times in latency.items():
            median = statistics.median(times)
            page.add_row(path + (" (anchor)" if path.startswith("/static") else ""), f"{median * 1000:.1f}",
                         f"{max(times) * 1000:.1f}", f"{median / anchor:.1f}", f"{median / GOAL_PAGE_S:.3f}")
        console.print(page)
        console.print(f"trend flag (|t| or |z| > {health.TREND_T_THRESHOLD:g}, latest {health.RECENT_TAPS} vs "
                      f"{health.BASELINE_TAPS} before): {len(flagged & expected)}/{len(expected)} changed printers "
                      f"flagged, {len(flagged - expected)}/{args.printers - len(expected)} unchanged printers flagged")
    finally:
        cluster.stop()
        import shutil

        shutil.rmtree(folder, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
