// ippc web view: keeps a page up to date from its server-sent events.
// Every value is set with textContent (text, never markup); links and chart
// images get paths built from the page's own templates and encoded keys.
// The events (see docs/web.md):
//   {"type": "rows", "reset": bool, "rows": [{"table", "key", "cells": {...}, "remove"?}]}
//   {"type": "fields", "fields": {...}}  ("layout": reload when it is not the page's)
// A cell is a value, or {"text", "state"?, "href"?} (its own colour and link).
"use strict";
(function () {
  const body = document.body;
  const url = body.dataset.events;
  if (!url) return;
  const conn = document.getElementById("conn");
  let events = 0;

  function status(text, state) {
    if (!conn) return;
    conn.textContent = text;
    conn.dataset.state = state;
  }

  function fill(url, key) {
    return url.split("{key}").join(encodeURIComponent(key));
  }

  function findRow(tbody, key) {
    for (const tr of tbody.children) {
      if (tr.dataset.key === key) return tr;
    }
    return null;
  }

  function setChart(img, key, value) {
    if (value === undefined || value === null) return;
    const v = String(value);
    if (img.dataset.v === v) return;
    img.dataset.v = v;
    img.src = fill(img.dataset.chart, key) + "?v=" + encodeURIComponent(v);
  }

  function localPath(href) {
    return typeof href === "string" && href.startsWith("/") && !href.startsWith("//");
  }

  // a cell {"text", "state"?, "href"?}: its own state (colour) and a link
  // to a path of this view (anything else is not made a link)
  function setRichCell(el, value) {
    const text = value.text === null || value.text === undefined ? "" : String(value.text);
    if (value.state === undefined || value.state === null) delete el.dataset.state;
    else el.dataset.state = String(value.state);
    if (localPath(value.href)) {
      let a = el.firstElementChild;
      if (!a || a.tagName !== "A") {
        a = document.createElement("a");
        el.replaceChildren(a);
      }
      a.setAttribute("href", value.href);
      a.textContent = text;
    } else {
      el.textContent = text;
    }
  }

  function setCells(tr, key, cells, stateField) {
    for (const el of tr.querySelectorAll("[data-field]")) {
      const name = el.dataset.field;
      if (Object.prototype.hasOwnProperty.call(cells, name)) {
        const value = cells[name];
        if (value !== null && typeof value === "object" && el.tagName === "TD") {
          setRichCell(el, value);
        } else {
          el.textContent = value === null || value === undefined ? "" : String(value);
        }
      }
    }
    for (const a of tr.querySelectorAll("a[data-href]")) {
      a.href = fill(a.dataset.href, key);
    }
    for (const img of tr.querySelectorAll("img[data-chart]")) {
      setChart(img, key, cells[img.dataset.version]);
    }
    if (stateField && Object.prototype.hasOwnProperty.call(cells, stateField)) {
      tr.dataset.state = String(cells[stateField]);
    }
  }

  function applyRows(ev) {
    if (ev.reset) {
      for (const tbody of document.querySelectorAll("tbody[data-table]")) {
        tbody.replaceChildren();
      }
    }
    const tables = new Map();
    for (const tbody of document.querySelectorAll("tbody[data-table]")) {
      tables.set(tbody.dataset.table, tbody);
    }
    for (const row of ev.rows || []) {
      const tbody = tables.get(row.table);
      if (!tbody) continue;
      const key = String(row.key);
      let tr = findRow(tbody, key);
      if (row.remove) {
        if (tr) tr.remove();
        continue;
      }
      const newestFirst = tbody.dataset.order === "newest-first";
      if (!tr) {
        const tpl = tbody.parentElement.querySelector("template");
        if (!tpl || !tpl.content.firstElementChild) continue;
        tr = tpl.content.firstElementChild.cloneNode(true);
        tr.dataset.key = key;
        if (newestFirst) tbody.prepend(tr);
        else tbody.append(tr);
        const limit = parseInt(tbody.dataset.limit || "0", 10);
        while (limit > 0 && tbody.children.length > limit) {
          (newestFirst ? tbody.lastElementChild : tbody.firstElementChild).remove();
        }
      }
      setCells(tr, key, row.cells || {}, tbody.dataset.stateField);
    }
  }

  function applyFields(ev) {
    const fields = ev.fields || {};
    // the tables' columns changed (e.g. a run's planners, known once it starts)
    if (
      body.dataset.layout !== undefined &&
      Object.prototype.hasOwnProperty.call(fields, "layout") &&
      String(fields.layout) !== body.dataset.layout
    ) {
      source.close();
      window.location.reload();
      return;
    }
    for (const el of document.querySelectorAll("[data-page-field]")) {
      const name = el.dataset.pageField;
      if (Object.prototype.hasOwnProperty.call(fields, name)) {
        const value = fields[name];
        el.textContent = value === null || value === undefined ? "" : String(value);
      }
    }
    for (const img of document.querySelectorAll("img[data-page-chart]")) {
      const name = img.dataset.version;
      if (Object.prototype.hasOwnProperty.call(fields, name)) {
        const v = String(fields[name]);
        if (img.dataset.v !== v) {
          img.dataset.v = v;
          img.src = img.dataset.pageChart + "?v=" + encodeURIComponent(v);
        }
      }
    }
  }

  const source = new EventSource(url);
  source.onopen = function () {
    status("live", "open");
  };
  source.onerror = function () {
    status("reconnecting", "closed");
  };
  source.onmessage = function (msg) {
    let ev;
    try {
      ev = JSON.parse(msg.data);
    } catch (err) {
      return;
    }
    if (ev.type === "rows") applyRows(ev);
    else if (ev.type === "fields") applyFields(ev);
    events += 1;
    body.dataset.eventsSeen = String(events);
  };
})();
