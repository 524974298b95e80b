"""Tap history end to end: two virtual printers behind two real Moonrakers, one
`tapcell monitor --moonraker a=... --moonraker b=... --db sqlite:///...`, `tapcell web` on the
store, and headless Chromium (Debian's, driven by Playwright) reading the pages.

Checks: the fleet, printer and tap pages draw numbers that match the store; a new PROBE shows
on an open page within 2 s of reaching the store, without a reload; a second monitor on the
same printer does not duplicate taps; hostile query strings get an error page, never a
traceback; no request leaves 127.0.0.1 and the console shows no error. One screenshot per page
is kept in the test's temp folder.
"""

from __future__ import annotations

import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from conftest import free_port, running_stack, stop, wait_for
from real_packages import unavailable

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--no-first-run"]
LIVE_DEADLINE_S = 2.0
HOSTILE = ["/printer/a?status=%3Cscript%3Ealert(1)%3C/script%3E", "/printer/a?cause=x'%20OR%201=1--",
           "/printer/a?mesh=-1", "/printer/a?mesh=99999999999999999999999", "/printer/a?mesh=77",
           "/printer/%3Cimg%20src=x%3E", "/printer/a/tap/999999", "/printer/a/tap/99999999999999999999999", "/printer/a?base=abc",
           "/printer/a?mesh=%D9%A3",
           "/api/printer/a/taps?after=%00", "/printer/a?cause=" + "A" * 5000]


def script(stack, text: str) -> None:
    status, body = stack.get("/printer/gcode/script?script=" + urllib.parse.quote(text), timeout_s=180.0)
    assert status == 200, body


def http_status(url: str) -> tuple[int, str]:
    try:
        with urllib.request.urlopen(url, timeout=10) as answer:
            return answer.status, answer.read().decode()
    except urllib.error.HTTPError as error:
        return error.code, error.read().decode()


class Farm:
    def __init__(self, folder: Path, a, b):
        self.folder, self.a, self.b = folder, a, b
        self.db = f"sqlite:///{folder / 'taps.db'}"
        self.processes: list[subprocess.Popen] = []
        self.web_url = ""

    def start_monitor(self, *printers: str, name: str) -> tuple[subprocess.Popen, Path]:
        said = self.folder / f"{name}.stderr"
        command = [sys.executable, "-m", "tapcell", "monitor", "--db", self.db]
        for printer in printers:
            command += ["--moonraker", printer]
        process = subprocess.Popen(command, stdout=(self.folder / f"{name}.stdout").open("w"),
                                   stderr=said.open("w"))
        self.processes.append(process)
        return process, said

    def store(self):
        from tapcell.store import Store

        return Store(self.db, create=False)

    def tap_ids(self, printer: str) -> list[int]:
        with self.store() as store:
            found = store.printer(printer)
            return [] if found is None else [row["id"] for row in store.taps(found["id"], limit=10_000)]


@pytest.fixture(scope="module")
def farm(tmp_path_factory):
    if not CHROMIUM.exists():
        unavailable(f"{CHROMIUM} is missing: 'make browser' installs Debian's chromium")
    try:
        import playwright  # noqa: F401
    except ImportError:
        unavailable("playwright is not installed: 'make browser' installs it from PyPI")
    from tapcell.tools.web.app import missing_assets

    if missing_assets():
        unavailable("uPlot is missing: 'make web-assets' fetches it from the npm registry")
    folder = tmp_path_factory.mktemp("farm")
    with running_stack(tmp_path_factory) as a, running_stack(tmp_path_factory) as b:
        farm = Farm(folder, a, b)
        try:
            # A third printer that is off: retried every second without holding up a and b.
            monitor, said = farm.start_monitor(f"a={a.url}", f"b={b.url}", f"gone=http://127.0.0.1:{free_port()}",
                                               name="monitor")
            wait_for(lambda: said.read_text().count("waiting for taps") == 2, 60.0, "the monitor to follow both", monitor)
            script(a, "G28\nBED_MESH_CALIBRATE PROBE_COUNT=3,3\nG1 X100 Y100 F6000\nPROBE\nPROBE")
            script(b, "G28\nBED_MESH_CALIBRATE PROBE_COUNT=3,3\nG1 X60 Y80 F6000\nPROBE\nPROBE\nPROBE")
            wait_for(lambda: len(farm.tap_ids("a")) >= 11 and len(farm.tap_ids("b")) >= 12, 60.0,
                     "the monitor to store the taps", monitor)
            with farm.store() as store:
                for name in ("a", "b"):
                    wait_for(lambda: store.meshes(store.printer(name)["id"]), 30.0, f"the monitor to store {name}'s mesh",
                             monitor)
            port = free_port()
            web = subprocess.Popen([sys.executable, "-m", "tapcell", "web", "--db", farm.db, "--port", str(port)],
                                   stdout=subprocess.DEVNULL, stderr=(folder / "web.stderr").open("w"))
            farm.processes.append(web)
            farm.web_url = f"http://127.0.0.1:{port}"
            wait_for(lambda: _answers(farm.web_url), 60.0, "tapcell web to answer", web)
            yield farm
        finally:
            for process in farm.processes:
                stop(process)


def _answers(url: str) -> bool:
    try:
        return http_status(url + "/")[0] == 200
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return False


@pytest.fixture
def browser_page(farm, tmp_path):
    """A Chromium page that records every request's host and every console error."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS)
        context = browser.new_context(viewport={"width": 1200, "height": 900})
        page = context.new_page()
        page.requests_seen, page.errors_seen = [], []  # of every page of the context
        context.on("request", lambda request: page.requests_seen.append(request.url))
        context.on("console", lambda message: page.errors_seen.append(message.text) if message.type == "error" else None)
        context.on("weberror", lambda error: page.errors_seen.append(str(error.error)))
        try:
            yield page
        finally:
            hosts = {urllib.parse.urlsplit(url).hostname for url in page.requests_seen
                     if not url.startswith(("data:", "blob:"))}
            browser.close()
        assert hosts <= {"127.0.0.1"}, f"requests left 127.0.0.1: {sorted(hosts)}"
        assert page.errors_seen == [], page.errors_seen


def show(page, url: str, drawn: str, screenshot: Path) -> None:
    """Open a page, wait until its JavaScript has drawn (`drawn` is true), keep a screenshot."""
    page.goto(url)
    page.wait_for_function(drawn)
    page.screenshot(path=str(screenshot), full_page=True)


def test_fleet_page_shows_both_printers_with_store_numbers(farm, browser_page, tmp_path):
    page = browser_page
    show(page, farm.web_url + "/", "Object.keys(window.tapcellCharts).length >= 2", tmp_path / "fleet.png")
    with farm.store() as store:
        fleet = {row["name"]: row for row in store.fleet()}
    assert set(fleet) == {"a", "b"}
    for name, row in fleet.items():
        cells = page.locator(f'tr[data-printer="{name}"]')
        assert cells.locator(".taps").inner_text() == str(row["taps"])
        assert cells.locator(".tapcell-z").inner_text() == f"{row['last']['tapcell_z_mm']:.4f}"
        assert cells.locator(".printer-z").inner_text() == f"{row['last']['printer_z_mm']:.4f}"
        assert cells.locator(".noise").inner_text() == f"{row['noise_sigma_g']:.3f}"
        # The trend chart draws the store's noise series, tap by tap.
        drawn = page.evaluate(f"window.tapcellCharts['fleet-{name}'].data")
        with farm.store() as store:
            taps = sorted(store.taps(row["id"], limit=1000), key=lambda tap: tap["id"])
        assert drawn[0] == [tap["id"] for tap in taps]
        assert drawn[1] == pytest.approx([tap["noise_sigma_g"] for tap in taps], abs=5e-5)
    assert "when |t| or |z| > 4.0 (two-sided p" in page.inner_text("body")
    assert [span.inner_text() for span in page.locator('tr[data-printer="a"] .t').all()] == ["n/a"] * 3  # < 60 taps


@pytest.mark.parametrize("name", ["a", "b"])
def test_printer_page_draws_the_stored_mesh_and_bed_map(farm, browser_page, tmp_path, name):
    page = browser_page
    show(page, farm.web_url + f"/printer/{name}", "window.tapcellCharts.mesh !== undefined", tmp_path / "printer.png")
    with farm.store() as store:
        printer_id = store.printer(name)["id"]
        mesh = store.meshes(printer_id)[0]
        spots = store.bed_spots(printer_id)
    drawn = page.evaluate("window.tapcellCharts.mesh")
    assert drawn["matrix"] == mesh["matrix"]
    assert len(mesh["matrix"]) == 3 and len(mesh["matrix"][0]) == 3
    canvas = page.locator("#mesh")
    assert float(canvas.get_attribute("data-min-z")) == min(min(row) for row in mesh["matrix"])
    assert float(canvas.get_attribute("data-max-z")) == max(max(row) for row in mesh["matrix"])
    colours = page.evaluate("""() => { const c = document.getElementById('mesh');
        const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; const seen = new Set();
        for (let k = 0; k < d.length; k += 4 * 97) seen.add(d[k] + ',' + d[k+1] + ',' + d[k+2]); return seen.size; }""")
    assert colours >= 4  # a heat map, not a blank canvas
    assert page.evaluate("window.tapcellCharts.bed.x_mm.length") == len(spots)
    rows = page.locator("#taps tbody tr")
    assert rows.count() == len(farm.tap_ids(name))


def test_tap_page_plots_the_stored_tap(farm, browser_page, tmp_path):
    page = browser_page
    tap_id = farm.tap_ids("b")[0]
    show(page, f"{farm.web_url}/printer/b/tap/{tap_id}", "window.tapcellCharts.z !== undefined", tmp_path / "tap.png")
    with farm.store() as store:
        row = store.tap(store.printer("b")["id"], tap_id)
    document = row["document"]
    assert page.inner_text("#tapcell-z") == f"{document['analysis']['z']:.4f}"
    assert page.inner_text("#printer-z") == f"{document['printer']['z']:.4f}"
    forces = page.evaluate("window.tapcellCharts.tap.force_g")
    assert forces == pytest.approx([round(f, 3) for f in document["force"]], abs=1e-9)
    drawn_points = page.evaluate("window.tapcellCharts.time.data[2].filter(v => v != null).length")
    assert drawn_points == len(document["analysis"]["points"]) == 6
    assert page.inner_text("#tap-cause") == "kept by the printer and by tapcell"


def test_a_printer_that_is_off_is_retried_without_holding_up_the_others(farm):
    said = (farm.folder / "monitor.stderr").read_text()
    assert said.count("[gone] tapcell monitor: connection to ws://127.0.0.1:") >= 2  # tried again
    assert "lost or refused (ConnectionRefusedError" in said
    assert len(farm.tap_ids("a")) >= 11 and len(farm.tap_ids("b")) >= 12
    with farm.store() as store:
        assert store.printer("gone") is None  # no tap, no row


def test_a_new_probe_appears_without_reload_and_a_second_monitor_adds_no_duplicate(farm, browser_page):
    page = browser_page
    fleet = page.context.new_page()  # the fleet page, open beside the printer's
    fleet.goto(farm.web_url + "/")
    fleet.wait_for_selector("#live.on")
    page.goto(farm.web_url + "/printer/b")
    page.wait_for_selector("#live.on")
    before = farm.tap_ids("b")
    second, said = farm.start_monitor(f"b={farm.b.url}", name="second-monitor")
    wait_for(lambda: "waiting for taps" in said.read_text(), 60.0, "the second monitor to follow b", second)
    script(farm.b, "G1 X90 Y90 F6000\nPROBE")
    wait_for(lambda: len(farm.tap_ids("b")) > len(before), 60.0, "the new tap in the store")
    new_id = farm.tap_ids("b")[0]
    page.wait_for_selector(f'#taps tr[data-tap="{new_id}"]', timeout=LIVE_DEADLINE_S * 1000)
    count = len(before) + 1
    fleet.wait_for_function(f"document.querySelector('tr[data-printer=\"b\"] .taps').textContent === '{count}'",
                            timeout=LIVE_DEADLINE_S * 1000)
    assert fleet.evaluate("window.tapcellCharts['fleet-b'].data[0].at(-1)") == new_id
    wait_for(lambda: "already kept" in said.read_text() or "already kept" in
             (farm.folder / "monitor.stderr").read_text(), 30.0, "a monitor to find the tap already kept")
    assert len(farm.tap_ids("b")) == len(before) + 1
    # A new mesh: the printer's page offers it without a reload.
    with farm.store() as store:
        printer_id = store.printer("b")["id"]
        meshes_before = len(store.meshes(printer_id))
        script(farm.b, "BED_MESH_CALIBRATE PROBE_COUNT=3,3")
        wait_for(lambda: len(store.meshes(printer_id)) > meshes_before, 60.0, "the new mesh in the store")
        newest = store.meshes(printer_id)[0]["id"]
    page.wait_for_selector("#new-mesh:not([hidden])", timeout=LIVE_DEADLINE_S * 1000)
    assert page.get_attribute("#new-mesh a", "href") == f"?mesh={newest}"
    assert page.evaluate("performance.getEntriesByType('navigation').length") == 1  # no reload


def test_hostile_query_strings_get_an_error_page_not_a_traceback(farm, browser_page):
    for path in HOSTILE:
        status, body = http_status(farm.web_url + path)
        assert status in (400, 404), (path, status)
        assert "Traceback" not in body and "<script>alert" not in body and "<img src=x>" not in body
        assert 'id="error-message"' in body or '"error"' in body, (path, body[:300])
    page = browser_page
    response = page.goto(farm.web_url + HOSTILE[0])
    assert response.status == 400
    assert page.inner_text("#error-message") == "status: '<script>alert(1)</script>' is not one of all, valid, rejected"
    # The browser logs the page's own 400 as a console error: that one, and nothing else.
    page.errors_seen.remove("Failed to load resource: the server responded with a status of 400 (Bad Request)")
