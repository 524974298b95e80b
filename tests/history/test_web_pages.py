"""`tapcell web`'s pages over a store on SQLite and on PostgreSQL, served by uvicorn in this
process and read as HTML: the filters, the mesh difference, the faulty_region suggestion, the
tap page's numbers, the errors for bad ids (the browser test reads them drawn, on SQLite)."""

from __future__ import annotations

import html
import json
import re
import socket
import threading
import time
import urllib.error
import urllib.request

import pytest
import uvicorn

from tapcell.store import Store
from tapcell.tools.web.app import create_app

from store_fixtures import pg_cluster, store_url  # noqa: F401  (the fixtures)
from test_store import tap_document

SHAPE_ERROR = {"error_code": "TAP_SHAPE_INVALID", "message": "no dwell"}


@pytest.fixture
def served(store_url):  # noqa: F811  (the fixture above)
    """A store with printer 'p': 4 kept taps, 4 rejected at one spot, two meshes; its pages' base URL."""
    with Store(store_url) as store:
        documents = [tap_document(seed, 20.0 + 40 * seed, 20.0) for seed in range(4)]
        documents += [tap_document(10 + k, 150.0 + k, 100.0 + k, is_valid=False, error=SHAPE_ERROR) for k in range(4)]
        store.add_taps("p", documents, recorded_s=1000.0)
        grid = {"profile_name": "default", "mesh_min": [10.0, 10.0], "mesh_max": [210.0, 210.0]}
        store.add_mesh("p", dict(grid, probed_matrix=[[0.0, 0.1], [0.2, 0.3]]), recorded_s=1.0)
        store.add_mesh("p", dict(grid, probed_matrix=[[0.02, 0.1], [0.2, 0.25]]), recorded_s=2.0)
        store.add_mesh("p", dict(grid, probed_matrix=[[0.0, 0.1, 0.2]]), recorded_s=3.0)
        with socket.socket() as probe:
            probe.bind(("127.0.0.1", 0))
            port = probe.getsockname()[1]
        server = uvicorn.Server(uvicorn.Config(create_app(store), host="127.0.0.1", port=port, log_level="error"))
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        deadline = time.monotonic() + 30
        while not server.started:
            assert time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.05)
        try:
            yield f"http://127.0.0.1:{port}", store
        finally:
            server.should_exit = True
            thread.join(timeout=10)


def get(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=30) as answer:
            return answer.status, answer.read().decode()
    except urllib.error.HTTPError as error:
        return error.code, error.read().decode()


def tap_ids(page: str) -> list[int]:
    return [int(found) for found in re.findall(r'<tr data-tap="(\d+)"', page)]


def embedded(page: str, element_id: str):
    found = re.search(rf'<script type="application/json" id="{element_id}">(.*?)</script>', page, re.S)
    return json.loads(html.unescape(found.group(1)))


def test_the_tap_list_filters_by_status_and_cause(served):
    url, store = served
    printer_id = store.printer("p")["id"]
    rejected = sorted(row["id"] for row in store.taps(printer_id, status="rejected"))
    assert len(rejected) == 4
    status, page = get(url + "/printer/p?status=rejected")
    assert status == 200 and sorted(tap_ids(page)) == rejected
    assert sorted(tap_ids(get(url + "/printer/p?status=valid")[1])) == sorted(
        set(row["id"] for row in store.taps(printer_id)) - set(rejected))
    assert sorted(tap_ids(get(url + "/printer/p?cause=TAP_SHAPE_INVALID")[1])) == rejected
    assert tap_ids(get(url + "/printer/p?cause=LOW_TAP_QUALITY")[1]) == []


def test_the_bed_map_suggests_the_failing_spot(served):
    url, _ = served
    page = get(url + "/printer/p")[1]
    assert "faulty_region_1_min: 148.0, 98.0\nfaulty_region_1_max: 155.0, 105.0" in page
    bed = embedded(page, "bed-data")
    assert sum(bed["rejected"]) == 4 and len(bed["x_mm"]) == 8


def test_the_mesh_difference_and_a_mismatched_pair(served):
    url, store = served
    meshes = {mesh["recorded_s"]: mesh["id"] for mesh in store.meshes(store.printer("p")["id"])}
    page = get(url + f"/printer/p?mesh={meshes[2.0]}&base={meshes[1.0]}")[1]
    difference = embedded(page, "mesh-data")
    assert sum(difference["matrix"], []) == pytest.approx([0.02, 0.0, 0.0, -0.05], abs=1e-12)
    assert (difference["min_z_mm"], difference["max_z_mm"]) == pytest.approx((-0.05, 0.02), abs=1e-12)
    status, page = get(url + f"/printer/p?mesh={meshes[3.0]}&base={meshes[1.0]}")
    assert status == 200
    assert f"mesh {meshes[3.0]} (3×1 over [10.0, 10.0, 210.0, 210.0]) and mesh {meshes[1.0]} (2×2" in page


def test_the_tap_page_shows_both_results_and_the_cause(served):
    url, store = served
    printer_id = store.printer("p")["id"]
    row = store.taps(printer_id, status="rejected", limit=1)[0]
    page = get(url + f"/printer/p/tap/{row['id']}")[1]
    assert f'<strong id="tapcell-z">{row["tapcell_z_mm"]:.4f}</strong>' in page
    assert f'<strong id="printer-z">{row["printer_z_mm"]:.4f}</strong>' in page
    assert "printer: TAP_SHAPE_INVALID - no dwell" in page
    plot = embedded(page, "tap-data")
    assert len(plot["z_mm"]) == len(plot["force_g"]) == len(plot["time_s"])
    assert plot["time_s"][0] == 0.0 and len(plot["fit_time_s"]) == 6


@pytest.mark.parametrize("path, status, message", [
    ("/printer/q", 404, "no printer named &#39;q&#39; in this store"),
    ("/printer/p/tap/424242", 404, "no tap 424242 for printer &#39;p&#39;"),
    ("/printer/p/tap/99999999999999999999", 404, "no tap 99999999999999999999"),
    ("/printer/p?mesh=0", 400, "mesh: &#39;0&#39; is not a whole number ≥ 1"),
    ("/printer/p?status=all%27--", 400, "status: &#34;all&#39;--&#34; is not one of all, valid, rejected"),
])
def test_bad_ids_and_values_get_a_page_that_says_so(served, path, status, message):
    url, _ = served
    answer_status, page = get(url + path)
    assert answer_status == status
    assert message in page and "Traceback" not in page
