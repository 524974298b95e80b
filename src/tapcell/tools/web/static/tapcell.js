// tapcell web: draws the plots (uPlot, served by tapcell itself) and follows the store live.
"use strict";
const tapcell = (() => {
  const charts = {};
  const FLEET_REFRESH_MS = 3000;
  const readJson = (id) => JSON.parse(document.getElementById(id).textContent);
  const fmt = (value, digits) => (value === null || value === undefined) ? "–" : Number(value).toFixed(digits);

  function live(onChange) {
    const badge = document.getElementById("live");
    const source = new EventSource("/events");
    source.addEventListener("hello", () => badge.classList.add("on"));
    source.addEventListener("change", (event) => {
      badge.classList.add("on");
      onChange(JSON.parse(event.data));
    });
    source.addEventListener("problem", (event) => {  // the server cannot read the store now
      badge.classList.remove("on");
      badge.title = JSON.parse(event.data);
    });
    source.onerror = () => badge.classList.remove("on");
    window.addEventListener("pagehide", () => source.close());
  }

  // Colour of t in 0..1: blue (low) through white to red (high).
  function colour(t) {
    const clamp = Math.max(0, Math.min(1, t));
    const low = [33, 102, 172], mid = [247, 247, 247], high = [178, 24, 43];
    const [a, b, u] = clamp < 0.5 ? [low, mid, clamp * 2] : [mid, high, (clamp - 0.5) * 2];
    return `rgb(${a.map((v, i) => Math.round(v + (b[i] - v) * u)).join(",")})`;
  }

  function drawMesh(canvas, mesh) {
    const context = canvas.getContext("2d");
    const rows = mesh.matrix.length, columns = mesh.matrix[0].length;
    const width = canvas.width / columns, height = canvas.height / rows;
    const span = mesh.max_z_mm - mesh.min_z_mm || 1;
    context.font = `${Math.max(9, Math.min(14, width / 5))}px sans-serif`;
    context.textAlign = "center";
    context.textBaseline = "middle";
    mesh.matrix.forEach((row, j) => row.forEach((z, i) => {
      const y = canvas.height - (j + 1) * height;  // row 0 is the front (Y min), drawn at the bottom
      context.fillStyle = colour((z - mesh.min_z_mm) / span);
      context.fillRect(i * width, y, width, height);
      if (columns <= 12) {
        context.fillStyle = "#000";
        context.fillText(z.toFixed(span < 0.01 ? 4 : 3), (i + 0.5) * width, y + height / 2);
      }
    }));
    canvas.dataset.minZ = mesh.min_z_mm;
    canvas.dataset.maxZ = mesh.max_z_mm;
    charts.mesh = mesh;
  }

  function drawBed(canvas, bed, bounds) {
    const context = canvas.getContext("2d");
    const xs = bed.x_mm.concat(bounds ? [bounds[0], bounds[2]] : []);
    const ys = bed.y_mm.concat(bounds ? [bounds[1], bounds[3]] : []);
    if (!xs.length) return;
    const pad = 10;
    const x0 = Math.min(...xs) - pad, x1 = Math.max(...xs) + pad, y0 = Math.min(...ys) - pad, y1 = Math.max(...ys) + pad;
    const scale = Math.min(canvas.width / (x1 - x0), canvas.height / (y1 - y0));
    const px = (x) => (x - x0) * scale, py = (y) => canvas.height - (y - y0) * scale;
    context.strokeStyle = "#b71c1c";
    context.lineWidth = 2;
    bed.regions.forEach((r) => context.strokeRect(px(r.x_min_mm), py(r.y_max_mm),
                                                  (r.x_max_mm - r.x_min_mm) * scale, (r.y_max_mm - r.y_min_mm) * scale));
    bed.x_mm.forEach((x, k) => {
      context.fillStyle = bed.rejected[k] ? "rgba(183,28,28,0.8)" : "rgba(96,125,139,0.5)";
      context.beginPath();
      context.arc(px(x), py(bed.y_mm[k]), bed.rejected[k] ? 4 : 3, 0, 2 * Math.PI);
      context.fill();
      if (bed.retried[k]) {  // a retry after a rejected tap: a ring around the spot
        context.strokeStyle = "#ef6c00";
        context.lineWidth = 1.5;
        context.beginPath();
        context.arc(px(x), py(bed.y_mm[k]), 7, 0, 2 * Math.PI);
        context.stroke();
      }
    });
    charts.bed = bed;
  }

  function tapRow(printer, tap) {
    const row = document.createElement("tr");
    row.dataset.tap = tap.id;
    const rejected = !tap.tapcell_valid || tap.printer_valid === false;
    row.className = (rejected ? "rejected " : "") + "fresh";
    const diff = (tap.tapcell_z_mm !== null && tap.printer_z_mm !== null)
      ? ((tap.tapcell_z_mm - tap.printer_z_mm) * 1000).toFixed(1) : "–";
    const valid = (v) => v === null ? "–" : (v ? "valid" : "bad");
    const cells = [null, new Date(tap.recorded_s * 1000).toLocaleString(), fmt(tap.x_mm, 2), fmt(tap.y_mm, 2),
                   fmt(tap.printer_z_mm, 4), fmt(tap.tapcell_z_mm, 4), diff,
                   `${valid(tap.printer_valid)}/${valid(tap.tapcell_valid)}`, fmt(tap.quality, 1), tap.cause];
    cells.forEach((text, k) => {
      const cell = document.createElement("td");
      if (k === 0) {
        const link = document.createElement("a");
        link.href = `/printer/${encodeURIComponent(printer)}/tap/${tap.id}`;
        link.textContent = tap.id;
        cell.appendChild(link);
      } else {
        cell.textContent = text;
      }
      row.appendChild(cell);
    });
    return row;
  }

  function printerPage() {
    const meshCanvas = document.getElementById("mesh");
    let bounds = null;
    if (meshCanvas) {
      const mesh = readJson("mesh-data");
      drawMesh(meshCanvas, mesh);
      bounds = mesh.bounds_mm;
    }
    drawBed(document.getElementById("bed"), readJson("bed-data"), bounds);
    const table = document.getElementById("taps");
    const printer = table.dataset.printer;
    let latest = Number(table.dataset.latest);
    const newMesh = document.getElementById("new-mesh");
    let latestMesh = Number(newMesh.dataset.latest);
    let busy = false;
    live(async (ids) => {
      if (busy) return;
      busy = true;
      try {
        if (ids.mesh > latestMesh) {  // some printer has a new mesh: is it this one's?
          latestMesh = ids.mesh;
          const meshes = await (await fetch(`/api/printer/${encodeURIComponent(printer)}/meshes`)).json();
          if (meshes.length && meshes[0].id > Number(newMesh.dataset.latest)) {
            newMesh.querySelector("a").href = `?mesh=${meshes[0].id}`;
            newMesh.hidden = false;
          }
        }
        const query = new URLSearchParams({status: table.dataset.status, cause: table.dataset.cause, after: latest});
        const answer = await fetch(`/api/printer/${encodeURIComponent(printer)}/taps?${query}`);
        if (!answer.ok) return;
        const taps = await answer.json();
        const body = table.tBodies[0];
        taps.slice().reverse().forEach((tap) => {  // oldest first, each on top
          if (tap.id > latest) {
            body.insertBefore(tapRow(printer, tap), body.firstChild);
            latest = tap.id;
          }
        });
        table.dataset.latest = latest;
      } finally {
        busy = false;
      }
    });
  }

  function fleetPage() {
    const fleet = readJson("fleet-data");
    fleet.forEach((printer) => {
      const target = document.getElementById(`spark-${printer.id}`);
      const series = printer.series;
      if (!target || series.id.length < 2) return;
      charts[`fleet-${printer.name}`] = new uPlot({
        width: 260, height: 70, legend: {show: false}, cursor: {show: false},
        scales: {x: {time: false}},
        axes: [{show: false}, {size: 40, font: "9px sans-serif"}],
        series: [{}, {label: "noise σ (g)", stroke: "#455a64", width: 1}],
      }, [series.id, series.noise_sigma_g], target);
    });
    // The fleet's numbers take a query per page view: refresh at once on a change, then at most
    // every FLEET_REFRESH_MS while taps keep coming (50 printers tapping change it many times a second).
    let last = 0, pending = null;
    const refreshSoon = () => {
      if (pending) return;
      pending = setTimeout(async () => {
        last = Date.now();
        try { await refreshFleet(); } finally { pending = null; }
      }, Math.max(0, last + FLEET_REFRESH_MS - Date.now()));
    };
    live(refreshSoon);
    async function refreshFleet() {
      const answer = await fetch("/api/fleet");
      if (!answer.ok) return;
      (await answer.json()).forEach((printer) => {
        const row = document.querySelector(`tr[data-printer-id="${printer.id}"]`);
        if (!row) return;
        row.querySelector(".taps").textContent = printer.taps;
        if (printer.last) {
          row.querySelector(".last").textContent = new Date(printer.last.recorded_s * 1000).toLocaleString();
          row.querySelector(".printer-z").textContent = fmt(printer.last.printer_z_mm, 4);
          row.querySelector(".tapcell-z").textContent = fmt(printer.last.tapcell_z_mm, 4);
        }
        row.querySelector(".repeatability").textContent = fmt(printer.repeatability_um, 2);
        row.querySelector(".stiffness").textContent = fmt(printer.stiffness_g_um, 2);
        row.querySelector(".noise").textContent = fmt(printer.noise_sigma_g, 3);
        row.querySelector(".rejection").textContent =
          printer.rejection_rate === null ? "–" : `${(printer.rejection_rate * 100).toFixed(1)} %`;
        const chart = charts[`fleet-${printer.name}`];
        if (chart) chart.setData([printer.series.id, printer.series.noise_sigma_g]);
      });
    }
  }

  // A vertical line at each Z value (printer's, tapcell's) on the force-Z chart.
  function zMarkers(markers) {
    return {hooks: {draw: [(u) => {
      const context = u.ctx;
      markers.forEach(([z, colour]) => {
        if (z === null || z === undefined) return;
        const x = u.valToPos(z, "x", true);
        context.save();
        context.strokeStyle = colour;
        context.setLineDash([6, 4]);
        context.lineWidth = 2;
        context.beginPath();
        context.moveTo(x, u.bbox.top);
        context.lineTo(x, u.bbox.top + u.bbox.height);
        context.stroke();
        context.restore();
      });
    }]}};
  }

  function tapPage() {
    const tap = readJson("tap-data");
    const width = Math.min(900, document.body.clientWidth - 40);
    const timeData = uPlot.join([[tap.time_s, tap.force_g], [tap.fit_time_s, tap.fit_force_g]]);
    charts.time = new uPlot({
      width, height: 300, scales: {x: {time: false}},
      axes: [{label: "time (s)"}, {label: "force (g)"}],
      series: [{label: "t (s)"}, {label: "force (g)", stroke: "#455a64", points: {show: false}},
               {label: "fitted lines", stroke: "#d84315", width: 2, spanGaps: true}],
    }, timeData, document.getElementById("plot-time"));
    if (tap.z_mm) {
      // The approach and the pullback each sorted by Z (uPlot wants rising x), on one Z axis.
      const turn = tap.z_mm.indexOf(Math.min(...tap.z_mm));
      const phase = (from, to) => {
        const pairs = tap.z_mm.slice(from, to).map((z, k) => [z, tap.force_g[from + k]]).sort((a, b) => a[0] - b[0]);
        return [pairs.map((p) => p[0]), pairs.map((p) => p[1])];
      };
      const zData = uPlot.join([phase(0, turn + 1), phase(turn + 1, tap.z_mm.length)]);
      charts.z = new uPlot({
        width, height: 300, scales: {x: {time: false}},
        axes: [{label: "Z (mm)"}, {label: "force (g)"}],
        series: [{label: "Z (mm)"}, {label: "approach", stroke: "#1565c0", spanGaps: true},
                 {label: "pullback", stroke: "#2e7d32", spanGaps: true}],
        plugins: [zMarkers([[tap.printer_z_mm, "#6a1b9a"], [tap.tapcell_z_mm, "#d84315"]])],
      }, zData, document.getElementById("plot-z"));
    }
    charts.tap = tap;
  }

  return {fleetPage, printerPage, tapPage, charts};
})();
window.tapcellCharts = tapcell.charts;
