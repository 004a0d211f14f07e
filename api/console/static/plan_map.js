// fleetbus console: a new mission's plan on the team's map, drawn with Leaflet (vendored) in its
// simple CRS, where a point is (y, x) in the map frame's metres, as on the live map.
//
// On the form (#plan-map data-mode="edit") the geofence and the points of interest are drawn with
// Leaflet-Geoman (vendored): a polygon or a rectangle is the geofence (one: a new one replaces
// it), each marker a point of interest. The form's text fields stay what is sent: a drawing
// writes them (a vertex `x y` a line; a point `name, x, y[, note]` a line, named `point N` until
// renamed there) and typing in them draws the map again, so the form is the same without this
// script, and the server reads and checks it alone. On the summary (data-mode="show") the map
// shows the plan the page lists (#summary-geofence, #summary-pois).
(function () {
  "use strict";
  const view = document.getElementById("plan-map");
  if (!view || !window.L) return;
  const editing = view.dataset.mode === "edit";
  if (editing && !L.PM) return;
  const fenceField = document.querySelector("textarea[name=geofence]");
  const poiField = document.querySelector("textarea[name=points_of_interest]");

  view.hidden = false;
  const help = document.getElementById("plan-map-help");
  if (help) help.hidden = false;
  const map = L.map(view, { crs: L.CRS.Simple, minZoom: -6, maxZoom: 8, zoomSnap: 0.25 });
  map.attributionControl.setPrefix(false);
  map.setView([0, 0], 3); // a view first: Leaflet adds no layer to a map without one
  const shapes = L.featureGroup().addTo(map);

  const frame = document.getElementById("plan-frame");
  let frameBounds = null;
  if (frame && frame.dataset.image) {
    const [west, south, east, north] = frame.dataset.bounds.split(" ").map(Number);
    frameBounds = L.latLngBounds([south, west], [north, east]);
    const overlay = L.imageOverlay(frame.dataset.image, frameBounds, {
      alt: frame.dataset.alt || "",
      className: "map-image",
      pmIgnore: true, // the map is not a shape to edit or to snap to
      snapIgnore: true,
    }).addTo(map);
    overlay.getElement().id = "plan-image";
  }

  // --- the plan: from the form's fields (edit) or the summary's lists (show) ---------------------

  function point(x, y) {
    return Number.isFinite(x) && Number.isFinite(y) ? { x, y } : null;
  }

  function fenceLine(text) {
    const parts = text.replace(/,/g, " ").split(/\s+/).filter(Boolean);
    return parts.length === 2 ? point(Number(parts[0]), Number(parts[1])) : null;
  }

  function poiLine(text, line) {
    const parts = text.split(",");
    if (parts.length < 3 || !parts[1].trim() || !parts[2].trim()) return null;
    const at = point(Number(parts[1]), Number(parts[2]));
    return at && { name: parts[0].trim(), x: at.x, y: at.y, line: line };
  }

  function fromFields() {
    const fence = fenceField.value.split("\n").map(fenceLine).filter(Boolean);
    const pois = poiField.value.split("\n").map(poiLine).filter(Boolean);
    return { fence, pois };
  }

  function fromLists() {
    const read = (item) => ({ name: item.dataset.name, x: Number(item.dataset.x), y: Number(item.dataset.y) });
    const fence = Array.from(document.querySelectorAll("#summary-geofence li[data-x]")).map(read);
    const pois = Array.from(document.querySelectorAll("#summary-pois li[data-x]")).map(read);
    return { fence, pois };
  }

  // --- drawing ---------------------------------------------------------------------------------

  function icon(name) {
    const box = document.createElement("div");
    const glyph = document.createElement("span");
    glyph.className = "glyph";
    const label = document.createElement("span");
    label.className = "label";
    label.textContent = name;
    box.append(glyph, label);
    return L.divIcon({ className: "mark poi", html: box, iconSize: null });
  }

  function draw(plan) {
    shapes.clearLayers();
    if (plan.fence.length >= 2) {
      const polygon = L.polygon(plan.fence.map((p) => [p.y, p.x]), { className: "geofence", weight: 2, fillOpacity: 0.12 });
      polygon.addTo(shapes);
      polygon.getElement().dataset.vertices = String(plan.fence.length);
      if (editing) {
        polygon.on("pm:edit", function () {
          writeFence(polygon.getLatLngs()[0]);
          polygon.getElement().dataset.vertices = String(polygon.getLatLngs()[0].length);
        });
      }
    }
    for (const poi of plan.pois) {
      const marker = L.marker([poi.y, poi.x], { icon: icon(poi.name), title: poi.name + " (" + poi.x + ", " + poi.y + ")" });
      marker.addTo(shapes);
      Object.assign(marker.getElement().dataset, { poi: poi.name, x: String(poi.x), y: String(poi.y) });
      marker.poiLine = poi.line;
      if (editing) marker.on("pm:edit", () => movePoi(marker));
    }
  }

  function fit(plan) {
    const points = plan.fence.concat(plan.pois).map((p) => L.latLng(p.y, p.x));
    if (points.length) map.fitBounds(L.latLngBounds(points).pad(0.25), { maxZoom: 6 });
    else if (frameBounds) map.fitBounds(frameBounds);
    else map.fitBounds([[0, 0], [40, 60]]); // no map stored: a plain 60 x 40 m field
  }

  if (!editing) {
    const plan = fromLists();
    draw(plan);
    fit(plan);
    view.dataset.ready = "yes";
    return;
  }

  // --- editing: what is drawn is written into the fields -----------------------------------------

  function metres(value) {
    return String(Math.round(value * 100) / 100); // to the centimetre
  }

  function writeFence(latlngs) {
    fenceField.value = latlngs.map((at) => metres(at.lng) + " " + metres(at.lat)).join("\n");
  }

  function poiLines() {
    return poiField.value.split("\n");
  }

  function movePoi(marker) {
    const at = marker.getLatLng();
    const lines = poiLines();
    const parts = lines[marker.poiLine].split(",");
    parts[1] = " " + metres(at.lng);
    parts[2] = " " + metres(at.lat);
    lines[marker.poiLine] = parts.join(",");
    poiField.value = lines.join("\n");
    Object.assign(marker.getElement().dataset, { x: metres(at.lng), y: metres(at.lat) });
  }

  function removePoi(line) {
    const lines = poiLines();
    lines.splice(line, 1);
    poiField.value = lines.join("\n");
  }

  function addPoi(at) {
    const names = new Set(fromFields().pois.map((poi) => poi.name));
    let n = 1;
    while (names.has("point " + n)) n += 1;
    const text = poiField.value.replace(/\s+$/, "");
    poiField.value = (text ? text + "\n" : "") + "point " + n + ", " + metres(at.lng) + ", " + metres(at.lat);
  }

  map.pm.addControls({
    position: "topleft",
    drawMarker: true,
    drawPolygon: true,
    drawRectangle: true,
    drawPolyline: false,
    drawCircle: false,
    drawCircleMarker: false,
    drawText: false,
    editMode: true,
    dragMode: false,
    cutPolygon: false,
    rotateMode: false,
    removalMode: true,
  });
  // Geoman titles each button's container, not the button a keyboard or screen reader lands on
  for (const button of map.getContainer().querySelectorAll(".leaflet-buttons-control-button")) {
    const title = button.parentElement.getAttribute("title");
    if (title && !button.hasAttribute("aria-label")) button.setAttribute("aria-label", title);
  }
  map.on("pm:create", function (event) {
    const layer = event.layer;
    layer.remove(); // drawn again from the fields, as everything else
    if (event.shape === "Marker") addPoi(layer.getLatLng());
    else writeFence(layer.getLatLngs()[0]);
    draw(fromFields());
  });
  map.on("pm:remove", function (event) {
    const layer = event.layer;
    if (layer instanceof L.Marker) {
      removePoi(layer.poiLine);
    } else {
      fenceField.value = "";
    }
    draw(fromFields());
  });
  for (const field of [fenceField, poiField]) field.addEventListener("input", () => draw(fromFields()));

  const plan = fromFields();
  draw(plan);
  fit(plan);
  view.dataset.ready = "yes";
})();
