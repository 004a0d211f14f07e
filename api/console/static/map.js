// fleetbus console: the live map, drawn with Leaflet (vendored) in its simple CRS, where a point
// is (y, x) in the map frame's metres.
//
// The server renders what the map shows as data: #map-frame names the stored image and the world
// rectangle it covers; #map-marks lists the robots, beacons and hazards with their coordinates,
// #map-news the provisional marks of hazards just reported.
// The live stream (live.js) and the version select (htmx) replace those elements; this redraws
// the map from them, keeping the view (the first shows where the team is, or else the whole map). Clicking a robot centres the map on it and follows it
// until the map is dragged. Trails over a chosen window come from /console/map/trails (the stored
// poses, and the window's hazards with the times of their steps); the time slider replays
// them: the team as it stood at a past moment, with the hazards as they were then.
(function () {
  "use strict";
  const view = document.getElementById("map-view");
  if (!view || !window.L) return;
  const panel = view.closest(".map-panel");
  const followingText = document.getElementById("map-following");
  const windowSelect = document.getElementById("trail-window");
  const grain = document.getElementById("trail-grain");
  const slider = document.getElementById("map-time");
  const moment = document.getElementById("map-moment");

  const map = L.map(view, {
    crs: L.CRS.Simple,
    minZoom: -6,
    maxZoom: 8,
    zoomSnap: 0.25,
    zoomControl: true,
  });
  map.attributionControl.setPrefix(false);
  map.setView([0, 0], 3); // a view first: Leaflet adds no layer to a map without one
  const layers = {
    trails: L.layerGroup().addTo(map),
    marks: L.layerGroup().addTo(map),
    past: L.layerGroup().addTo(map),
  };
  const markers = new Map(); // mark id -> marker
  let overlay = null;
  let imageKey = "";
  let following = null;
  let fitted = false;
  let trails = null; // {since, until, step, robots: {name: [[ms, x, y, heading], ...]}, hazards: [...]}

  function utc(ms) {
    return new Date(ms).toISOString().slice(0, 19).replace("T", " ") + " UTC";
  }

  function hue(name) {
    let h = 0;
    for (const c of name) h = (h * 31 + c.charCodeAt(0)) % 360;
    return h;
  }

  function showFrame() {
    const frame = document.getElementById("map-frame");
    const image = frame && frame.dataset.image;
    if ((image || "") === imageKey) return;
    imageKey = image || "";
    if (overlay) overlay.remove();
    overlay = null;
    if (!image) return;
    const [west, south, east, north] = frame.dataset.bounds.split(" ").map(Number);
    const bounds = L.latLngBounds([south, west], [north, east]);
    overlay = L.imageOverlay(image, bounds, { alt: frame.dataset.alt || "", className: "map-image" });
    overlay.addTo(map);
    overlay.bringToBack();
    overlay.getElement().id = "map-image";
  }

  function icon(item) {
    const box = document.createElement("div");
    const glyph = document.createElement("span");
    glyph.className = "glyph";
    if (item.dataset.heading) glyph.style.transform = "rotate(" + -Number(item.dataset.heading) + "deg)";
    const label = document.createElement("span");
    label.className = "label";
    label.textContent = item.dataset.label || "";
    box.append(glyph, label);
    return L.divIcon({ className: "mark " + item.className, html: box, iconSize: null });
  }

  function follow(name) {
    following = name;
    followingText.textContent = "Following " + name + " (drag the map to stop).";
    const marker = markers.get("mark-robot-" + name);
    if (marker) map.setView(marker.getLatLng(), Math.max(map.getZoom(), map.getMaxZoom() - 4));
    view.dataset.following = name;
  }

  function unfollow() {
    if (!following) return;
    following = null;
    delete view.dataset.following;
    followingText.textContent = "Click a robot to centre on it and follow it.";
  }

  // the marks to draw: those of the state, and a new hazard's provisional mark (sent at once, from
  // its event) until the state has the hazard registered (then the provisional one is dropped)
  function marksToDraw(list) {
    const items = Array.from(list.children);
    const news = document.getElementById("map-news");
    if (!news) return items;
    const registered = new Set(items.filter((item) => item.dataset.event).map((item) => item.dataset.event));
    for (const item of Array.from(news.children)) {
      if (registered.has(item.dataset.event)) item.remove();
      else items.push(item);
    }
    return items;
  }

  function showMarks() {
    const list = document.getElementById("map-marks");
    if (!list) return;
    const seen = new Set();
    const points = [];
    for (const item of marksToDraw(list)) {
      const at = L.latLng(Number(item.dataset.y), Number(item.dataset.x));
      seen.add(item.id);
      points.push(at);
      let marker = markers.get(item.id);
      const look = item.className + "|" + (item.dataset.heading || "") + "|" + (item.dataset.label || "");
      if (!marker) {
        marker = L.marker(at, { icon: icon(item), title: item.title, keyboard: true });
        marker.look = look;
        if (item.dataset.name) {
          const name = item.dataset.name;
          marker.on("click", function () {
            follow(name);
          });
        }
        marker.addTo(layers.marks);
        markers.set(item.id, marker);
      } else {
        marker.setLatLng(at);
        if (marker.look !== look) {
          marker.setIcon(icon(item));
          marker.look = look;
        }
        marker.options.title = item.title;
        marker.getElement().title = item.title;
      }
      const element = marker.getElement();
      element.dataset.mark = item.id;
      element.dataset.x = item.dataset.x;
      element.dataset.y = item.dataset.y;
      if (item.dataset.name && trails && atNow()) grow(item.dataset.name, at);
    }
    for (const [id, marker] of markers) {
      if (!seen.has(id)) {
        marker.remove();
        markers.delete(id);
      }
    }
    if (!fitted) {
      // first view: where the team is (robots, hazards, beacons), else the whole map
      if (points.length) map.fitBounds(L.latLngBounds(points).pad(0.3), { maxZoom: 5 });
      else if (overlay) map.fitBounds(overlay.getBounds());
      fitted = points.length > 0 || overlay !== null;
    }
    if (following) {
      const marker = markers.get("mark-robot-" + following);
      if (marker) map.panTo(marker.getLatLng(), { animate: false });
    }
  }

  // --- trails and the time slider ---------------------------------------------------------------

  function duration(ms) {
    const seconds = Math.max(1, Math.round(ms / 1000));
    if (seconds < 120) return seconds + " s";
    return Math.round(seconds / 60) + " min";
  }

  function atNow() {
    return slider.value === slider.max;
  }

  function sliderTime() {
    if (!trails) return null;
    return trails.since + ((trails.until - trails.since) * Number(slider.value)) / Number(slider.max);
  }

  function grow(name, at) {
    const line = layers.trails.byName && layers.trails.byName[name];
    if (!line) return;
    const points = line.getLatLngs();
    const last = points[points.length - 1];
    if (!last || !last.equals(at)) line.addLatLng(at);
  }

  // a hazard's state at a moment, from the times of its steps; null when it did not exist then
  function stateAt(hazard, at) {
    if (hazard.received > at || (hazard.cleared !== null && hazard.cleared <= at)) return null;
    for (const step of ["reached", "claimed", "announced"]) {
      if (hazard[step] !== null && hazard[step] <= at) return step;
    }
    return "held";
  }

  function drawPastHazards(until) {
    for (const hazard of trails.hazards || []) {
      const state = stateAt(hazard, until);
      if (!state) continue;
      const item = document.createElement("li");
      item.className = "hazard past state-" + state;
      item.dataset.label = hazard.label;
      const marker = L.marker(L.latLng(hazard.y, hazard.x), {
        icon: icon(item),
        title: "hazard " + hazard.label + " (" + state + " then): " + hazard.description,
        keyboard: false,
        interactive: false,
      }).addTo(layers.past);
      marker.getElement().dataset.pastHazard = hazard.id;
      marker.getElement().dataset.state = state;
    }
  }

  function drawTrails(until) {
    layers.trails.clearLayers();
    layers.past.clearLayers();
    layers.trails.byName = {};
    if (!trails) return;
    const past = until !== null;
    for (const [name, poses] of Object.entries(trails.robots)) {
      const shown = past ? poses.filter((pose) => pose[0] <= until) : poses;
      const points = shown.map((pose) => L.latLng(pose[2], pose[1]));
      const line = L.polyline(points, { color: "hsl(" + hue(name) + ", 70%, 40%)", weight: 3, opacity: 0.8, className: "trail", interactive: false });
      line.addTo(layers.trails);
      line.getElement && line.getElement() && line.getElement().setAttribute("data-robot", name);
      layers.trails.byName[name] = line;
      if (past && shown.length) {
        const pose = shown[shown.length - 1];
        const item = document.createElement("li");
        item.className = "robot past";
        item.dataset.heading = pose[3];
        item.dataset.label = name;
        L.marker(L.latLng(pose[2], pose[1]), {
          icon: icon(item),
          title: name + " at (" + pose[1].toFixed(2) + ", " + pose[2].toFixed(2) + "), " + utc(pose[0]),
          keyboard: false,
          interactive: false,
        })
          .addTo(layers.past)
          .getElement().dataset.past = name;
      }
    }
    if (past) drawPastHazards(until);
  }

  function showMoment() {
    if (!trails) {
      moment.textContent = "now";
      view.classList.remove("in-past");
      return;
    }
    if (atNow()) {
      moment.textContent = "now";
      view.classList.remove("in-past");
      drawTrails(null);
    } else {
      const when = sliderTime();
      moment.textContent = utc(when);
      view.classList.add("in-past");
      drawTrails(when);
    }
    view.dataset.moment = atNow() ? "now" : String(Math.round(sliderTime()));
  }

  async function loadTrails() {
    const minutes = windowSelect.value;
    slider.value = slider.max;
    grain.textContent = "";
    if (!minutes) {
      trails = null;
      slider.disabled = true;
      drawTrails(null);
      showMoment();
      delete view.dataset.trails;
      return;
    }
    view.dataset.trails = "loading";
    const answer = await fetch("/console/map/trails?minutes=" + encodeURIComponent(minutes), {
      credentials: "same-origin",
    });
    if (!answer.ok) {
      view.dataset.trails = "failed";
      moment.textContent = "trails not loaded (" + answer.status + ")";
      return;
    }
    trails = await answer.json();
    // a window with more poses than one answer holds comes sampled: each robot's last pose a step
    grain.textContent = trails.step ? "a pose per " + duration(trails.step) : "every pose";
    slider.disabled = false;
    showMoment();
    view.dataset.trails = "loaded";
  }

  windowSelect.addEventListener("change", loadTrails);
  slider.addEventListener("input", showMoment);
  map.on("dragstart", unfollow);

  // redraw when the live stream or the version select replaces the data the map is drawn from
  const redraw = new MutationObserver(function (changes) {
    if (changes.some((change) => !view.contains(change.target))) {
      showFrame();
      showMarks();
    }
  });
  redraw.observe(panel, { childList: true, subtree: true });

  showFrame();
  showMarks();
  view.dataset.ready = "yes";
})();
