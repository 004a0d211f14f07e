// fleetbus console: a mission's sensor data on a map, clustered and coloured by value.
//
// #mission-map names where to load the mission's readings (data-points-url: the newest, up to the
// server's bound, as JSON: each a row [x, y, value, quantity, robot, epoch, seq, at ms], the texts
// by their index in lists of their own) and the mission's geofence (data-geofence: "x y;x y;..."). Leaflet
// (vendored) draws them in its simple CRS, where a point is (y, x) in the map frame's metres;
// Leaflet.markercluster (vendored) groups the points that lie close at the zoom shown, so
// thousands stay readable and fast. One quantity is shown at a time (a select when the mission
// has several). Each point, and each cluster by its mean, takes one of nine colours of a
// perceptually uniform scale over the quantity's range; the legend says which values each means.
//
// New readings come through the live stream (live.js) as empty <li> elements with their data,
// added to #mission-points-new: this takes each (once: a reading sent twice is drawn once),
// draws it, and removes the element. A reading outside the range so far widens it and recolours.
(function () {
  "use strict";
  const view = document.getElementById("mission-map");
  if (!view || !window.L || !L.markerClusterGroup) return;
  const select = document.getElementById("mission-quantity");
  const legend = document.getElementById("mission-legend");
  const range = document.getElementById("mission-range");
  const caption = document.getElementById("mission-map-caption");
  const incoming = document.getElementById("mission-points-new");
  const BINS = 9;

  const map = L.map(view, { crs: L.CRS.Simple, minZoom: -6, maxZoom: 10, zoomSnap: 0.25 });
  map.attributionControl.setPrefix(false);
  map.setView([0, 0], 2); // a view first: Leaflet adds no layer to a map without one

  const quantities = new Map(); // quantity -> {unit, points: [], min, max}
  const seen = new Set(); // ids of the readings taken in
  let shown = null; // the quantity drawn
  let group = null; // its clusters
  let ready = false; // the first load is in
  let fitted = false;
  let limit = 0;
  let more = false;

  const geofence = (view.dataset.geofence || "")
    .split(";")
    .filter(Boolean)
    .map((pair) => pair.split(" ").map(Number))
    .map(([x, y]) => [y, x]);
  const fence = geofence.length ? L.polygon(geofence, { className: "mp-geofence", interactive: false }) : null;
  if (fence) fence.addTo(map);

  function bin(value, q) {
    if (!(q.max > q.min)) return Math.floor(BINS / 2);
    return Math.min(BINS - 1, Math.max(0, Math.floor(((value - q.min) / (q.max - q.min)) * BINS)));
  }

  function short(value) {
    return String(Number(value.toPrecision(3)));
  }

  function utc(ms) {
    return new Date(ms).toISOString().slice(0, 19).replace("T", " ") + " UTC";
  }

  function tooltip(p, unit) {
    return function () {
      const box = document.createElement("span");
      box.textContent = `${p.quantity} ${short(p.value)}${unit ? " " + unit : ""} · ${p.robot} · ${utc(p.at)}`;
      return box;
    };
  }

  function marker(p, q) {
    const m = L.circleMarker([p.y, p.x], { radius: 6, className: "mp-point mp-bin-" + bin(p.value, q), value: p.value });
    m.bindTooltip(tooltip(p, q.unit));
    return m;
  }

  function clusterIcon(cluster) {
    const children = cluster.getAllChildMarkers();
    let sum = 0;
    for (const child of children) sum += child.options.value;
    const q = quantities.get(shown);
    const n = children.length;
    const size = n < 10 ? 30 : n < 100 ? 36 : n < 1000 ? 44 : 52;
    return L.divIcon({
      html: String(n),
      className: "mp-cluster mp-bin-" + bin(sum / n, q),
      iconSize: L.point(size, size),
    });
  }

  function showLegend(q) {
    legend.replaceChildren();
    range.textContent = "";
    if (!q || !q.points.length) return;
    const step = (q.max - q.min) / BINS;
    for (let i = 0; i < BINS; i += 1) {
      const item = document.createElement("li");
      const swatch = document.createElement("span");
      swatch.className = "swatch mp-bin-" + i;
      const label = document.createElement("span");
      label.textContent = q.max > q.min ? "≥ " + short(q.min + i * step) : i === Math.floor(BINS / 2) ? short(q.min) : "";
      item.append(swatch, label);
      legend.append(item);
    }
    range.textContent = `${shown}${q.unit ? " (" + q.unit + ")" : ""}: ${short(q.min)} to ${short(q.max)}`;
  }

  function describe() {
    const q = quantities.get(shown);
    const count = q ? q.points.length : 0;
    view.dataset.points = String(count);
    view.dataset.quantity = shown || "";
    let text = count
      ? `${count.toLocaleString("en")} readings of ${shown}`
      : "No sensor readings recorded under this mission yet.";
    if (more) text += ` (the newest ${limit.toLocaleString("en")} loaded; older ones are left out)`;
    caption.textContent = text;
  }

  function fit() {
    // once: the readings and the geofence in view (a drawn view is the user's from then on)
    if (fitted) return;
    const bounds = L.latLngBounds([]);
    const any = group && group.getLayers().length;
    if (any) bounds.extend(group.getBounds());
    if (fence) bounds.extend(fence.getBounds());
    if (!bounds.isValid()) return;
    map.fitBounds(bounds.pad(0.05), { maxZoom: 4, animate: false });
    fitted = Boolean(any);
  }

  function drawn() {
    describe();
    fit();
    if (!view.dataset.loadedMs) {
      requestAnimationFrame(() => (view.dataset.loadedMs = String(Math.round(performance.now()))));
    }
  }

  function draw() {
    // the shown quantity's points, coloured on its range now (in chunks: the page stays responsive)
    if (group) group.remove();
    group = null;
    const q = quantities.get(shown);
    showLegend(q);
    if (!q) {
      drawn();
      return;
    }
    group = L.markerClusterGroup({
      chunkedLoading: true,
      chunkProgress: (done, total) => done === total && drawn(),
      showCoverageOnHover: false,
      maxClusterRadius: 50,
      iconCreateFunction: clusterIcon,
    });
    group.addTo(map);
    group.addLayers(q.points.map((p) => marker(p, q)));
  }

  function options() {
    if (!select) return;
    const names = [...quantities.keys()].sort();
    if (names.join("\n") === [...select.options].map((o) => o.value).join("\n")) return;
    select.replaceChildren(
      ...names.map((name) => {
        const option = document.createElement("option");
        option.value = name;
        option.textContent = name;
        return option;
      })
    );
    select.value = shown || "";
    select.closest("label").hidden = names.length < 2;
  }

  function take(p) {
    // one reading into its quantity; true when the range it is drawn on changed
    if (seen.has(p.id)) return false;
    seen.add(p.id);
    let q = quantities.get(p.quantity);
    if (!q) {
      q = { unit: p.unit, points: [], min: p.value, max: p.value };
      quantities.set(p.quantity, q);
    }
    q.points.push(p);
    const widened = p.value < q.min || p.value > q.max;
    q.min = Math.min(q.min, p.value);
    q.max = Math.max(q.max, p.value);
    return widened;
  }

  function arrived(element) {
    const d = element.dataset;
    const p = {
      id: element.id,
      x: Number(d.x),
      y: Number(d.y),
      value: Number(d.value),
      quantity: d.quantity,
      unit: d.unit || "",
      robot: d.robot,
      at: Number(d.at),
    };
    element.remove();
    const fresh = !seen.has(p.id);
    const widened = take(p);
    if (!ready || !fresh) return;
    if (!shown) shown = p.quantity;
    options();
    const q = quantities.get(shown);
    if (p.quantity !== shown) return;
    if (widened || !group) {
      draw();
    } else {
      group.addLayer(marker(p, q));
      describe();
      fit();
    }
  }

  function drain() {
    for (const element of [...incoming.children]) arrived(element);
  }

  if (select) {
    select.addEventListener("change", function () {
      shown = select.value;
      fitted = false;
      draw();
    });
  }

  new MutationObserver(drain).observe(incoming, { childList: true });
  drain();

  fetch(view.dataset.pointsUrl, { credentials: "same-origin", headers: { Accept: "application/json" } })
    .then((response) => {
      if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
      return response.json();
    })
    .then((answer) => {
      limit = answer.limit;
      more = answer.more;
      for (const [x, y, value, q, r, e, seq, at] of answer.points) {
        const [quantity, unit] = answer.quantities[q];
        const robot = answer.robots[r];
        take({ id: `p-${robot}-${answer.epochs[e]}-${seq}`, x, y, value, quantity, unit, robot, at });
      }
      let most = 0;
      for (const [name, q] of quantities) {
        if (q.points.length > most) [shown, most] = [name, q.points.length];
      }
      ready = true;
      options();
      draw();
    })
    .catch((error) => {
      caption.textContent = "The sensor readings could not be loaded: " + error.message + ". Reload the page.";
      view.dataset.failed = "true";
    });
})();
