// fleetbus console: sorting and filtering what a page holds, in the browser.
//
// A <table class="sortable"> gets a button in each column's header (sort by it; again to reverse)
// and a filter field above it (rows holding every word typed). A <select data-filter-table="ID"
// data-column="N"> keeps only the rows whose column N says exactly the chosen value. A list of
// cards (<div data-sortable-list>) is sorted by a <select data-sort-list="ID"> (values
// "key:asc" or "key:desc", the key a data- attribute of each card) and filtered by an
// <input data-filter-list="ID">. Live updates replace tables and add rows; the choices are kept
// (by the table's or its section's id) and applied again to what arrives; a value that arrives in a
// filtered column (a new client's mission) becomes one of its select's choices.
(function () {
  "use strict";
  const chosen = new Map(); // table key -> {column, descending, text, focused, caret}
  const compare = new Intl.Collator(undefined, { numeric: true, sensitivity: "base" }).compare;

  function keyOf(table) {
    if (table.id) return table.id;
    const holder = table.closest("[id]");
    return holder ? holder.id : "";
  }

  function choice(table) {
    const key = keyOf(table);
    if (!chosen.has(key)) chosen.set(key, { column: -1, descending: false, text: "" });
    return chosen.get(key);
  }

  function cellText(row, column) {
    const cell = row.cells[column];
    return cell ? cell.textContent.trim() : "";
  }

  // what a row sorts by: the cell's data-sort (a time to the microsecond, a mission state's place
  // in its life cycle) where it has one, else what it shows
  function cellValue(row, column) {
    const cell = row.cells[column];
    if (!cell) return "";
    return cell.dataset.sort !== undefined ? cell.dataset.sort : cellText(row, column);
  }

  function byValue(a, b) {
    const x = parseFloat(a), y = parseFloat(b);
    if (!isNaN(x) && !isNaN(y) && /^-?[\d.]/.test(a) && /^-?[\d.]/.test(b) && x !== y) return x - y;
    return compare(a, b);
  }

  function words(text) {
    return text.toLowerCase().split(/\s+/).filter(Boolean);
  }

  function matches(element, wanted) {
    const text = element.textContent.toLowerCase();
    return wanted.every((word) => text.includes(word));
  }

  function sortChildren(parent, items, key, descending) {
    const sorted = items.slice().sort((a, b) => (descending ? -1 : 1) * byValue(key(a), key(b)));
    if (sorted.every((item, i) => item === items[i])) return;
    for (const item of sorted) parent.appendChild(item);
  }

  function offerValues(select, rows) {
    const offered = new Set(Array.from(select.options, (option) => option.value));
    const column = Number(select.dataset.column);
    for (const row of rows) {
      const value = cellText(row, column);
      if (value && !offered.has(value)) {
        offered.add(value);
        select.add(new Option(value, value));
      }
    }
  }

  function applyTable(table) {
    const body = table.tBodies[0];
    if (!body) return;
    const state = choice(table);
    const rows = Array.from(body.rows).filter((row) => !row.querySelector("td.empty"));
    if (state.column >= 0) sortChildren(body, rows, (row) => cellValue(row, state.column), state.descending);
    const wanted = words(state.text);
    const selects = document.querySelectorAll('select[data-filter-table="' + table.id + '"]');
    for (const select of selects) offerValues(select, rows);
    let shown = 0;
    for (const row of rows) {
      let keep = matches(row, wanted);
      for (const select of selects) {
        if (select.value && cellText(row, Number(select.dataset.column)) !== select.value) keep = false;
      }
      row.hidden = !keep;
      if (keep) shown += 1;
    }
    table.dataset.shown = String(shown);
    for (const [index, th] of Array.from(table.tHead ? table.tHead.rows[0].cells : []).entries()) {
      if (index === state.column) th.setAttribute("aria-sort", state.descending ? "descending" : "ascending");
      else th.removeAttribute("aria-sort");
    }
  }

  function enhanceTable(table) {
    if (table.dataset.enhanced) return;
    table.dataset.enhanced = "yes";
    const state = choice(table);
    const headers = table.tHead ? Array.from(table.tHead.rows[0].cells) : [];
    headers.forEach(function (th, index) {
      if (!th.textContent.trim() || th.dataset.nosort !== undefined) return;
      const button = document.createElement("button");
      button.type = "button";
      button.className = "sort";
      button.title = "sort by " + th.textContent.trim();
      button.append(...th.childNodes);
      th.append(button);
      button.addEventListener("click", function () {
        const current = choice(table);
        current.descending = current.column === index ? !current.descending : false;
        current.column = index;
        quietly(() => applyTable(table));
      });
    });
    const filter = document.createElement("input");
    filter.type = "search";
    filter.className = "table-filter";
    filter.placeholder = "filter";
    filter.setAttribute("aria-label", "filter the rows");
    filter.value = state.text;
    filter.addEventListener("input", function () {
      choice(table).text = filter.value;
      quietly(() => applyTable(table));
    });
    filter.addEventListener("focus", () => (choice(table).focused = true));
    filter.addEventListener("blur", () => (choice(table).focused = false));
    table.before(filter);
    if (state.focused) {
      filter.focus();
      filter.setSelectionRange(filter.value.length, filter.value.length);
    }
  }

  function applyList(list) {
    const sorter = document.querySelector('select[data-sort-list="' + list.id + '"]');
    const filter = document.querySelector('input[data-filter-list="' + list.id + '"]');
    const items = Array.from(list.children);
    if (sorter && sorter.value) {
      const [key, direction] = sorter.value.split(":");
      sortChildren(list, items, (item) => item.dataset[key] || "", direction === "desc");
    }
    const wanted = words(filter ? filter.value : "");
    let shown = 0;
    for (const item of items) {
      item.hidden = !matches(item, wanted);
      if (!item.hidden) shown += 1;
    }
    list.dataset.shown = String(shown);
  }

  function applyAll() {
    document.querySelectorAll("table.sortable").forEach(function (table) {
      enhanceTable(table);
      applyTable(table);
    });
    document.querySelectorAll("[data-sortable-list]").forEach(applyList);
  }

  // at most once a frame, however many changes (the map's panes change often while it moves)
  let pending = false;
  const observer = new MutationObserver(function () {
    if (pending) return;
    pending = true;
    requestAnimationFrame(function () {
      pending = false;
      quietly(applyAll);
    });
  });

  function quietly(work) {
    observer.disconnect();
    try {
      work();
    } finally {
      observer.takeRecords();
      observer.observe(document.body, { childList: true, subtree: true });
    }
  }

  document.addEventListener("input", function (event) {
    const target = event.target;
    if (target.matches && target.matches("[data-filter-table], [data-sort-list], [data-filter-list]")) {
      quietly(applyAll);
    }
  });
  document.addEventListener("change", function (event) {
    const target = event.target;
    if (target.matches && target.matches("[data-filter-table], [data-sort-list]")) quietly(applyAll);
  });
  quietly(applyAll);
})();
