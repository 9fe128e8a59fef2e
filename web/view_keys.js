// Keyboard jog in the station page's 3-D view, with the focus visible and every refusal said.
//
// Injected by the station after web/hold_worker.js: while the 3-D view (viser's canvas) has the keyboard focus
// (a click in it gives it; a blue frame and the "keyboard jog" badge show it), the arrows jog X / Y, PageUp /
// PageDown jog Z at the page's selected jog speed (Shift: fast), Esc or Space stops the machine. A held key is
// handed to the hold worker, which refreshes the jog every 40 ms over the pendant WebSocket as this page (the same
// jog-hold pipeline as every front end); letting go of the keys, or the view losing the focus, releases it.
// The keys are taken from viser's own camera keys while the view has the focus (the arrows would turn the view).
// What the station answers (not in control, FAULT, E-STOP, the end of the travel ...) is shown on the view.
(function () {
  if (window.__cmmViewKeys) return;
  window.__cmmViewKeys = true;
  var AXIS = { ArrowRight: ["x", 1], ArrowLeft: ["x", -1], ArrowUp: ["y", 1], ArrowDown: ["y", -1],
               PageUp: ["z", 1], PageDown: ["z", -1] };
  var GIZMO_PX = 100;  // the axis gizmo's corner of the view, left free
  var held = {}, shift = false, label = null, beat = null, canvas = null, badge = null, note = null, noteTimer = null;

  var style = document.createElement("style");
  style.textContent =
    "canvas.cmm-keys:focus { outline: 3px solid #1e88e5; outline-offset: -3px; }" +
    "#cmm-view-keys { position: fixed; z-index: 50; pointer-events: none; font: 12px system-ui, sans-serif;" +
    " padding: 4px 8px; border-radius: 4px; background: rgba(255,255,255,0.85); color: #555; max-width: 420px; }" +
    "#cmm-view-keys.on { background: #1e88e5; color: #fff; }" +
    "#cmm-view-keys-note { display: block; margin-top: 3px; font-weight: 600; }" +
    "#cmm-view-keys-note.error { color: #ffeb3b; }" +
    "#cmm-view-keys:not(.on) #cmm-view-keys-note.error { color: #c62828; }";
  document.head.appendChild(style);

  function worker() { return window.__cmmHoldWorker || null; }

  function place() {
    if (!canvas || !badge) return;
    var r = canvas.getBoundingClientRect();
    // right of viser's axis gizmo (the bottom-left 90 px of the view): the hint never covers it
    badge.style.left = (r.left + GIZMO_PX) + "px";
    badge.style.top = (r.bottom - badge.offsetHeight - 10) + "px";
  }

  function focused() { return canvas !== null && document.activeElement === canvas; }

  function showState() {
    if (!badge) return;
    var on = focused();
    badge.classList.toggle("on", on);
    badge.firstChild.textContent = on
      ? "Keyboard jog: arrows X/Y, PgUp/PgDn Z, Shift fast, Esc stop"
      : "Click the 3-D view to jog with the keyboard";
    place();
  }

  function say(text, isError) {
    if (!note) return;
    note.textContent = text;
    note.className = isError ? "error" : "";
    if (noteTimer) clearTimeout(noteTimer);
    noteTimer = setTimeout(function () { note.textContent = ""; place(); }, isError ? 6000 : 3000);
    place();
  }

  function currentLabel() {
    var parts = [];
    ["x", "y", "z"].forEach(function (axis) {
      var s = 0;
      Object.keys(held).forEach(function (k) { if (AXIS[k][0] === axis) s += AXIS[k][1]; });
      if (s) parts.push((s > 0 ? "+" : "-") + axis);
    });
    if (!parts.length) return null;
    return "keys " + parts.join(" ") + (shift ? " fast" : "");
  }

  function update() {
    var w = worker();
    var next = currentLabel();
    if (next === label) return;
    label = next;
    if (!w) { if (label) say("keyboard jog is not available: the pendant server is not running", true); return; }
    if (label) {
      w.postMessage({ type: "hold", button: label });
      if (beat === null) beat = setInterval(function () { w.postMessage({ type: "beat" }); }, 100);
    } else {
      if (beat !== null) { clearInterval(beat); beat = null; }
      w.postMessage({ type: "release" });
    }
  }

  function releaseAll() {
    held = {}; shift = false;
    update();
  }

  function onKeyDown(e) {
    if (!focused()) return;
    if (e.key === "Shift") { shift = true; update(); return; }
    if (e.key === "Escape" || e.key === " ") {
      e.preventDefault(); e.stopImmediatePropagation();
      releaseAll();
      var w = worker();
      if (w) w.postMessage({ type: "stop" });  // it falls back on the STOP button's click when its socket is closed
      else if (window.__cmmPressButton) window.__cmmPressButton("STOP");  // no jog worker: the STOP button's click
      say("STOP sent", false);
      return;
    }
    if (!AXIS[e.key]) return;
    e.preventDefault(); e.stopImmediatePropagation();  // not viser's camera keys
    shift = e.shiftKey;
    if (!held[e.key]) { held[e.key] = true; update(); }
  }

  function onKeyUp(e) {
    if (e.key === "Shift") { shift = false; update(); return; }
    if (!AXIS[e.key] || !held[e.key]) return;
    e.preventDefault(); e.stopImmediatePropagation();
    delete held[e.key];
    update();
  }

  // capture phase on window: before viser's document listeners see the keys
  window.addEventListener("keydown", onKeyDown, true);
  window.addEventListener("keyup", onKeyUp, true);
  window.addEventListener("blur", releaseAll);
  document.addEventListener("visibilitychange", function () { if (document.hidden) releaseAll(); });
  window.addEventListener("resize", place);
  window.addEventListener("cmm-pendant-message", function (e) {
    var m = e.detail || {};
    if (label === null && !focused()) return;  // the jog buttons' answers are told by the page itself
    if (m.type === "error") say(m.message, true);
    else if (m.type === "notice") say(m.message, false);
  });

  function attach() {
    var c = document.querySelector("canvas[data-engine]");
    if (!c) return false;
    canvas = c;
    canvas.tabIndex = 0;
    canvas.classList.add("cmm-keys");
    canvas.setAttribute("aria-label", "3-D view (click for keyboard jog)");
    canvas.addEventListener("pointerdown", function () { canvas.focus({ preventScroll: true }); }, true);
    canvas.addEventListener("focus", showState);
    canvas.addEventListener("blur", function () { releaseAll(); showState(); });
    badge = document.createElement("div");
    badge.id = "cmm-view-keys";
    badge.setAttribute("role", "status");
    badge.appendChild(document.createElement("span"));
    note = document.createElement("span");
    note.id = "cmm-view-keys-note";
    badge.appendChild(note);
    document.body.appendChild(badge);
    showState();
    setInterval(place, 1000);  // the panel may resize the view
    return true;
  }
  var tries = 0;
  (function again() { if (!attach() && ++tries < 2400) setTimeout(again, 250); })();  // a slow page: up to 10 min
})();
