// fleetbus console: keeps a page live from its server-sent event stream.
//
// The page's <main data-stream="URL" data-last-event-id="ID"> names its stream and what it
// already shows. Each "fragment" event carries a JSON list of fragments, each one HTML element
// with an id, parsed on its own (a <tr> parsed after a <section> would be dropped): it replaces
// the element with the same id, or, carrying data-into="LIST", is added at the top of that list
// (which keeps at most its data-max rows). The browser's EventSource reconnects by itself, sending
// Last-Event-ID; when it gives up, this opens a new one with the last id in the query, so a page
// that was cut off is always sent what it missed (or, when it missed more than the server
// replays, told to "reload").
(function () {
  "use strict";
  const main = document.querySelector("main[data-stream]");
  const status = document.getElementById("live-status");
  if (!main) return;
  let lastId = main.dataset.lastEventId || "";
  let source = null;
  let retry = 1000;

  function show(state, text) {
    if (!status) return;
    status.dataset.state = state;
    status.textContent = text;
  }

  function place(element) {
    const existing = element.id ? document.getElementById(element.id) : null;
    if (existing) {
      existing.replaceWith(element);
    } else if (element.dataset.into) {
      const list = document.getElementById(element.dataset.into);
      if (!list) return;
      list.prepend(element);
      const max = parseInt(list.dataset.max || "0", 10);
      while (max > 0 && list.children.length > max) list.lastElementChild.remove();
    } else {
      return;
    }
    if (window.htmx) window.htmx.process(element);
  }

  function apply(fragments) {
    for (const html of fragments) {
      const template = document.createElement("template");
      template.innerHTML = html;
      const element = template.content.firstElementChild;
      if (element) place(element);
    }
  }

  function connect() {
    const url = new URL(main.dataset.stream, window.location.href);
    if (lastId) url.searchParams.set("last_event_id", lastId);
    source = new EventSource(url);
    source.addEventListener("open", function () {
      retry = 1000;
      show("live", "live");
    });
    source.addEventListener("fragment", function (event) {
      if (event.lastEventId) lastId = event.lastEventId;
      apply(JSON.parse(event.data));
      main.dataset.lastEventId = lastId;
    });
    source.addEventListener("reload", function () {
      // it missed more than the server replays: the page as rendered now shows the newest;
      // or its session ended: loaded again, it goes to the login form
      source.close();
      window.location.reload();
    });
    source.addEventListener("error", function () {
      if (status && status.dataset.state !== "reconnecting") {
        // UTC, as every time the console shows
        show("reconnecting", "reconnecting… (since " + new Date().toISOString().slice(11, 19) + " UTC)");
      }
      if (source.readyState === EventSource.CLOSED) {
        source.close();
        setTimeout(connect, retry);
        retry = Math.min(retry * 2, 15000);
      }
    });
  }

  // A page left for another is closed: Chrome may keep it (back/forward cache) with its stream
  // open, and six open connections to one server stall every further request to it.
  window.addEventListener("pagehide", function () {
    if (source) source.close();
  });
  window.addEventListener("pageshow", function (event) {
    if (event.persisted) connect(); // back again: live from what it saw last
  });

  connect();
})();
