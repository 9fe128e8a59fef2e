// The viser page's jog buttons, refreshed off the page's main thread.
//
// While a "hold X +" ... button of the station page is pressed, viser sends hold events from the page's main
// thread, which a busy page (a WebGL frame of a few hundred ms on a slow PC) delays past the machine's
// 0.15 s dead-man. This script runs in the page (injected by the station) and hands the press to a Web
// Worker, whose timers a busy main thread does not hold up: the worker sends {"type": "hold", "button": label}
// every 40 ms over its own WebSocket to the pendant port, acting as this page (its grant token), until the
// button is let go ({"type": "release"}). The main thread beats every 100 ms while the button is held; a
// worker that hears no beat for MAIN_SILENT_MS (a frozen tab) stops on its own, and a closed tab or a lost
// network stops the machine by its dead-man 0.15 s after the worker's last message. The keyboard jog of the
// 3-D view (web/view_keys.js) holds through the same worker with a "keys +x -y [fast]" label and may send a
// STOP; the page's STOP and E-STOP buttons send their press through it too; what the station answers (a refusal and why) comes back as a "cmm-pendant-message" window event.
(function () {
  var WS_URL = "__WS_URL__", TOKEN = "__TOKEN__";
  // Click the page's button labelled ``label`` (its viser click): the fallback of a press the worker cannot carry,
  // here and in web/view_keys.js.
  window.__cmmPressButton = function (label) {
    var b = Array.prototype.find.call(document.querySelectorAll("button"),
                                      function (x) { return x.textContent.trim() === label; });
    if (b) b.click();
    return !!b;
  };
  if (window.__cmmHoldWorker) return;
  var src = [
    "var ws = null, timer = null, button = null, beat = 0, MAIN_SILENT_MS = 1000;",
    "function open() {",
    "  ws = new WebSocket(" + JSON.stringify(WS_URL) + ");",
    "  ws.onopen = function () { ws.send(JSON.stringify({type: 'hello', as: " + JSON.stringify(TOKEN) + "}));",
    "    postMessage({type: 'link', open: true}); };",
    "  ws.onclose = function () { ws = null; postMessage({type: 'link', open: false}); setTimeout(open, 500); };",
    "  ws.onmessage = function (e) { var m; try { m = JSON.parse(e.data); } catch (x) { return; }",
    "    if (m.type === 'error' || m.type === 'notice') postMessage(m); };",
    "}",
    "function send(m) { if (!ws || ws.readyState !== 1) return false; ws.send(JSON.stringify(m)); return true; }",
    "function tick() {",
    "  if (button === null) return;",
    "  if (Date.now() - beat > MAIN_SILENT_MS) { stop(true); return; }",
    "  send({type: 'hold', button: button});",
    "}",
    "function stop(lapse) {",
    "  if (timer !== null) { clearInterval(timer); timer = null; }",
    "  if (button !== null) send(lapse ? {type: 'release', lapse: true} : {type: 'release'});",
    "  button = null;",
    "}",
    "onmessage = function (e) {",
    "  var m = e.data;",
    "  if (m.type === 'hold') { button = m.button; beat = Date.now(); if (timer === null) timer = setInterval(tick, 40); tick(); }",
    "  else if (m.type === 'beat') { beat = Date.now(); }",
    "  else if (m.type === 'release') { stop(); }",
    "  else if (m.type === 'stop' || m.type === 'estop') {",
    "    stop(); postMessage({type: 'pressed', what: m.type, sent: send({type: m.type})}); }",
    "};",
    "open();"
  ].join("\n");
  var worker = new Worker(URL.createObjectURL(new Blob([src], {type: "text/javascript"})));
  window.__cmmHoldWorker = worker;
  var linkOpen = false, pressedAt = 0, viaViser = false;
  worker.onmessage = function (e) {
    if (e.data && e.data.type === "link") { linkOpen = !!e.data.open; return; }
    if (e.data && e.data.type === "pressed") { if (!e.data.sent) viserPress(e.data.what); return; }
    window.dispatchEvent(new CustomEvent("cmm-pendant-message", { detail: e.data }));
  };
  // A press the worker could not send (its socket closed after the page last heard it was open, or still
  // reconnecting) is never lost: the button's own viser click carries it (the keyboard's stop presses STOP).
  function viserPress(what) {
    var label = what === "estop" ? "E-STOP" : "STOP";
    console.warn("the " + label + " press went through the page's own connection: the jog link was not open");
    viaViser = true;
    try { window.__cmmPressButton(label); } finally { viaViser = false; }
  }
  // The page's STOP and E-STOP buttons: the press goes from here, on pointer-down, through the worker's own
  // WebSocket to the pendant port (a thread of its own in the station, straight to the modules), not through
  // viser's socket and its queue of frames, panels and callbacks. While that socket is not open the button's own
  // viser click carries the press instead (never both: the click is kept from viser when the worker sent it), and so
  // does a press the worker found its socket closed for.
  function stopButton(e) {
    var b = e.target && e.target.closest ? e.target.closest("button") : null;
    var label = b ? b.textContent.trim() : "";
    if ((label !== "STOP" && label !== "E-STOP") || !linkOpen || viaViser) return;
    e.preventDefault();
    e.stopImmediatePropagation();
    var now = Date.now();
    if (e.type === "click" && now - pressedAt < 2000) return;  // the pointer-down sent it already
    pressedAt = now;
    worker.postMessage({type: label === "STOP" ? "stop" : "estop"});
  }
  document.addEventListener("pointerdown", stopButton, true);
  document.addEventListener("click", stopButton, true);
  document.addEventListener("pointerdown", function (e) {
    var b = e.target && e.target.closest ? e.target.closest("button") : null;
    var label = b ? b.textContent.trim() : "";
    if (label.indexOf("hold ") !== 0) return;
    worker.postMessage({type: "hold", button: label});
    var beat = setInterval(function () { worker.postMessage({type: "beat"}); }, 100);
    var up = function () {
      clearInterval(beat);
      worker.postMessage({type: "release"});
      document.removeEventListener("pointerup", up, true);
      document.removeEventListener("pointercancel", up, true);
    };
    document.addEventListener("pointerup", up, true);
    document.addEventListener("pointercancel", up, true);
  }, true);
})();
