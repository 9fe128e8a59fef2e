// CMM jog pendant: keyboard, on-screen hold buttons and the Gamepad API over one WebSocket.
// Plain script, no build step. Protocol: see cmm/ui/pendant.py.
//
// Safety rules kept here:
// - a jog is re-sent every SEND_MS while an input is held; the server and the machine stop
//   the axes when the refreshes stop (dead-man), so a frozen tab cannot keep the machine moving;
// - releasing every input sends a "release" at once (keyup, pointerup/leave, stick back to centre);
// - window blur and a hidden page release everything; a gamepad must then return to centre
//   before it can jog again.
(function () {
  "use strict";

  var SEND_MS = 50;          // jog refresh period while an input is held
  var DEAD_ZONE = 0.15;      // stick deflection ignored around the centre
  var CURVE = 3;             // speed = max * s^3, s = deflection rescaled past the dead zone (fine near centre)
  var TRIGGER_DEAD = 0.05;

  var speeds = { jog_fast: 40, jog_slow: 10, jog_fine: 1 };
  var toldNoControl = false;
  var ws = null, connected = false, hasControl = false, isLocal = false, lanEnabled = false;
  var keyboard = {};           // held key -> true
  var held = [0, 0, 0];        // on-screen buttons: direction per axis
  var heldButtons = {};
  var padVel = [0, 0, 0];
  var padLatched = false;      // after blur: wait for the sticks to return to centre
  var padStopWasDown = false;
  var lastSent = [0, 0, 0], lastSendTime = 0, jogging = false;
  var messageTimer = null;
  var selectedSpeed = "jog_slow";
  // embedded in the station page: the page's grant (#as=TOKEN) makes this pendant act as the page's client
  var grant = (location.hash.match(/[#&]as=([^&]+)/) || [])[1] || null;
  var shared = false;

  var $ = function (id) { return document.getElementById(id); };
  if (window.self !== window.top) document.body.classList.add("embedded");

  function send(msg) {
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
  }

  function showMessage(text, isError) {
    var el = $("message");
    el.textContent = text;
    el.className = isError ? "error" : "";
    if (messageTimer) clearTimeout(messageTimer);
    messageTimer = setTimeout(function () { el.textContent = ""; }, isError ? 6000 : 3000);
  }

  // --- inputs -> one velocity --------------------------------------------------

  function shape(a) {
    var m = Math.abs(a);
    if (!(m > DEAD_ZONE)) return 0;
    var s = Math.min(1, (m - DEAD_ZONE) / (1 - DEAD_ZONE));
    return (a < 0 ? -1 : 1) * Math.pow(s, CURVE);
  }

  function pollGamepad() {
    var pads = navigator.getGamepads ? navigator.getGamepads() : [];
    var pad = null;
    for (var i = 0; pads && i < pads.length; i++) if (pads[i] && pads[i].connected !== false) { pad = pads[i]; break; }
    $("gamepad").textContent = pad ? "gamepad: " + (pad.id || "connected").slice(0, 24) : "no gamepad";
    if (!pad) { padVel = [0, 0, 0]; return; }
    var ax = pad.axes || [], bt = pad.buttons || [];
    var val = function (i) { var b = bt[i]; return b ? (typeof b === "object" ? (b.value || (b.pressed ? 1 : 0)) : b) : 0; };
    var down = function (i) { var b = bt[i]; return !!b && (typeof b === "object" ? b.pressed : b > 0.5); };
    var stopDown = down(1);
    if (stopDown && !padStopWasDown) stopNow();
    padStopWasDown = stopDown;
    var z = shape(-(ax[3] || 0));
    var rt = val(7), lt = val(6);
    if (rt > TRIGGER_DEAD || lt > TRIGGER_DEAD) z = Math.pow(rt, CURVE) - Math.pow(lt, CURVE);
    var s = [shape(ax[0] || 0), shape(-(ax[1] || 0)), z];   // stick up is negative on the Gamepad API
    var max = down(0) ? speeds.jog_fine : down(4) ? speeds.jog_slow : speeds.jog_fast;
    if (padLatched) {
      if (s[0] === 0 && s[1] === 0 && s[2] === 0) padLatched = false;
      padVel = [0, 0, 0];
      return;
    }
    padVel = s.map(function (x) { return x * max; });
  }

  function keyboardVel() {
    var v = [0, 0, 0];
    if (keyboard.ArrowRight) v[0] += 1;
    if (keyboard.ArrowLeft) v[0] -= 1;
    if (keyboard.ArrowUp) v[1] += 1;
    if (keyboard.ArrowDown) v[1] -= 1;
    if (keyboard.PageUp) v[2] += 1;
    if (keyboard.PageDown) v[2] -= 1;
    var max = keyboard.Shift ? speeds.jog_fast : speeds[selectedSpeed];
    return v.map(function (x) { return x * max; });
  }

  function velocity() {
    var limit = speeds.jog_fast, v = [0, 0, 0];
    var k = keyboardVel(), b = held.map(function (d) { return d * speeds[selectedSpeed]; });
    for (var i = 0; i < 3; i++) v[i] = Math.max(-limit, Math.min(limit, padVel[i] + k[i] + b[i]));
    return v;
  }

  function tick() {
    pollGamepad();
    var v = velocity();
    var moving = v[0] !== 0 || v[1] !== 0 || v[2] !== 0;
    var now = performance.now();
    if (moving && hasControl) {
      var changed = v[0] !== lastSent[0] || v[1] !== lastSent[1] || v[2] !== lastSent[2];
      if (changed || now - lastSendTime >= SEND_MS - 4) {
        send({ type: "jog", v: v });
        lastSent = v; lastSendTime = now; jogging = true;
      }
    } else if (jogging) {
      release();
    }
    // a jog held without control (the gamepad; keys and buttons say so when pressed) is told once per hold
    if (moving && !hasControl && !toldNoControl) showMessage("take control to jog", true);
    toldNoControl = moving && !hasControl;
  }

  function release() {
    send({ type: "release" });
    jogging = false; lastSent = [0, 0, 0]; lastSendTime = performance.now();
  }

  function releaseAll(latchPad) {
    keyboard = {};
    held = [0, 0, 0];
    Object.keys(heldButtons).forEach(function (k) { heldButtons[k].classList.remove("held"); });
    heldButtons = {};
    if (latchPad) { padLatched = true; padVel = [0, 0, 0]; }
    if (jogging) release();
  }

  function stopNow() {
    releaseAll(false);
    send({ type: "stop" });
  }

  function estopNow() {
    releaseAll(false);
    send({ type: "estop" });
  }

  function loop() {
    tick();
    window.requestAnimationFrame(loop);
  }
  window.requestAnimationFrame(loop);
  setInterval(tick, SEND_MS);   // keeps refreshing where animation frames are throttled (embedded, background)

  // --- keyboard --------------------------------------------------------------------

  var JOG_KEYS = { ArrowRight: 1, ArrowLeft: 1, ArrowUp: 1, ArrowDown: 1, PageUp: 1, PageDown: 1 };
  function typing(e) { var t = e.target; return t && (t.tagName === "INPUT" || t.tagName === "TEXTAREA"); }

  // step mode (keys 1-4): one press of an arrow / PageUp / PageDown = one step of that size
  var stepSize = 0;
  var STEP_KEYS = { "0": 0, "1": 0.01, "2": 0.1, "3": 1, "4": 10 };
  var STEP_AXIS = { ArrowRight: [0, 1], ArrowLeft: [0, -1], ArrowUp: [1, 1], ArrowDown: [1, -1],
                    PageUp: [2, 1], PageDown: [2, -1] };
  function selectStep(size) {
    stepSize = size;
    Array.prototype.forEach.call(document.querySelectorAll(".steps button"), function (b) {
      b.classList.toggle("sel", +b.dataset.step === size);
    });
  }
  Array.prototype.forEach.call(document.querySelectorAll(".steps button"), function (btn) {
    btn.addEventListener("click", function () { selectStep(+btn.dataset.step); });
  });

  window.addEventListener("keydown", function (e) {
    if (typing(e)) return;
    if (e.key === "Shift") { keyboard.Shift = true; tick(); return; }
    if (e.key === "Escape" || e.key === " ") { e.preventDefault(); stopNow(); return; }
    if (e.key in STEP_KEYS) { e.preventDefault(); releaseAll(false); selectStep(STEP_KEYS[e.key]); return; }
    if (!JOG_KEYS[e.key]) return;
    e.preventDefault();
    if (stepSize > 0) {
      if (!e.repeat) {
        if (!hasControl) { showMessage("take control to jog", true); return; }
        var a = STEP_AXIS[e.key];
        send({ type: "step", axis: a[0], mm: a[1] * stepSize });
      }
      return;
    }
    keyboard.Shift = e.shiftKey;
    if (!keyboard[e.key]) { keyboard[e.key] = true; tick(); }
  });
  window.addEventListener("keyup", function (e) {
    if (e.key === "Shift") { keyboard.Shift = false; tick(); return; }
    if (!JOG_KEYS[e.key] || stepSize > 0) return;
    e.preventDefault();
    delete keyboard[e.key];
    tick();                      // sends the release now when nothing else is held
  });
  window.addEventListener("blur", function () { releaseAll(true); });
  document.addEventListener("visibilitychange", function () { if (document.hidden) releaseAll(true); });
  window.addEventListener("pagehide", function () { releaseAll(true); });

  // --- on-screen hold buttons -----------------------------------------------------------

  Array.prototype.forEach.call(document.querySelectorAll(".pad button[data-axis]"), function (btn) {
    var axis = +btn.dataset.axis, dir = +btn.dataset.dir, id = btn.className.split(" ")[0];
    var down = function (e) {
      e.preventDefault();
      if (!hasControl) { showMessage("take control to jog", true); return; }
      held[axis] = dir; heldButtons[id] = btn; btn.classList.add("held"); tick();
    };
    var up = function (e) {
      if (!heldButtons[id]) return;
      e.preventDefault();
      if (held[axis] === dir) held[axis] = 0;
      delete heldButtons[id]; btn.classList.remove("held"); tick();
    };
    btn.addEventListener("pointerdown", down);
    btn.addEventListener("pointerup", up);
    btn.addEventListener("pointerleave", up);
    btn.addEventListener("pointercancel", up);
    btn.addEventListener("contextmenu", function (e) { e.preventDefault(); });
  });
  document.querySelector(".pad .stop").addEventListener("pointerdown", function (e) { e.preventDefault(); stopNow(); });
  $("stop").addEventListener("pointerdown", function (e) { e.preventDefault(); stopNow(); });
  $("stop").addEventListener("keydown", function (e) { if (e.key === "Enter") stopNow(); });
  $("estop").addEventListener("pointerdown", function (e) { e.preventDefault(); estopNow(); });
  $("estop").addEventListener("keydown", function (e) { if (e.key === "Enter") estopNow(); });

  Array.prototype.forEach.call(document.querySelectorAll(".speeds button"), function (btn) {
    btn.addEventListener("click", function () {
      selectedSpeed = btn.dataset.speed;
      Array.prototype.forEach.call(document.querySelectorAll(".speeds button"), function (b) {
        b.classList.toggle("sel", b === btn);
      });
    });
  });

  // --- control --------------------------------------------------------------------

  function take() {
    var code = $("code").value.trim();
    send({ type: "take", code: code || null });
  }
  $("take").addEventListener("click", take);
  $("code").addEventListener("keydown", function (e) { if (e.key === "Enter") { e.preventDefault(); take(); } });
  $("observe").addEventListener("click", function () { releaseAll(false); send({ type: "observe" }); });

  // a station with users: log in first (the station checks every command against the user's role)
  function login() {
    send({ type: "login", user: $("user").value.trim(), password: $("password").value });
    $("password").value = "";
  }
  $("login-button").addEventListener("click", login);
  $("password").addEventListener("keydown", function (e) { if (e.key === "Enter") { e.preventDefault(); login(); } });

  function setControl(control, holder, holderName) {
    if (control !== hasControl) {
      hasControl = control;
      if (!control) releaseAll(false);
    }
    var el = $("control");
    el.className = control ? "you" : holder ? "other" : "";
    el.textContent = control ? (shared ? "you have control (with the station page)" : "you have control")
      : holder ? "observer: " + (holderName ? holderName + " has control" : "another client has control") : "observer";
    $("observe").disabled = !control;
    $("take").disabled = !connected || control;
    $("pad").classList.toggle("enabled", control);
  }

  // the machine's mode from the control core: a fault, E-stop or stop says so (and why), never "idle"
  var ALARM_MODES = ["fault", "e-stopped", "stopped", "not homed"];
  function motionText(msg) {
    if (msg.mode && msg.mode !== "idle" && msg.mode !== "moving" && msg.mode !== "jogging") {
      return msg.mode.toUpperCase() + (msg.reason ? ": " + msg.reason : "");
    }
    return msg.jogging ? "jogging" : msg.moving ? "moving" : "idle";
  }

  function fmt(x) { return (typeof x === "number" && isFinite(x)) ? x.toFixed(3) : "–"; }

  function onMessage(ev) {
    var msg;
    try { msg = JSON.parse(ev.data); } catch (e) { return; }
    if (msg.type === "state") {
      if (msg.pos) { $("px").textContent = fmt(msg.pos[0]); $("py").textContent = fmt(msg.pos[1]); $("pz").textContent = fmt(msg.pos[2]); }
      $("motion").textContent = motionText(msg);
      $("motion").className = ALARM_MODES.indexOf(msg.mode) >= 0 ? "alarm" : "";
      setControl(!!msg.control, msg.holder, msg.holder_name);
    } else if (msg.type === "hello") {
      if (msg.speeds) speeds = msg.speeds;
      isLocal = !!msg.local; lanEnabled = !!msg.lan; shared = !!msg.shared;
      $("code").placeholder = isLocal ? "no code needed here" : "access code";
      if (!isLocal && !lanEnabled && !msg.users) showMessage("this station only accepts control from its own computer", true);
      $("login").hidden = !msg.users;
    } else if (msg.type === "login") {
      $("login").hidden = true;
      showMessage("logged in as " + msg.user + " (" + msg.role + ")", false);
    } else if (msg.type === "control") {
      setControl(!!msg.control, msg.control ? "you" : null);
      showMessage(msg.control ? "you have control" : "control given back", false);
    } else if (msg.type === "error") {
      showMessage(msg.message, true);
    } else if (msg.type === "notice") {
      showMessage(msg.message, false);
    }
  }

  function connect() {
    var url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws";
    ws = new WebSocket(url);
    ws.onopen = function () {
      connected = true; $("link").classList.add("on");
      send(grant ? { type: "hello", as: decodeURIComponent(grant) } : { type: "hello" });
      setControl(false, null);
    };
    ws.onmessage = onMessage;
    ws.onclose = function () {
      var wasConnected = connected;
      connected = false; $("link").classList.remove("on");
      jogging = false; setControl(false, null);
      if (wasConnected) showMessage("connection to the station lost; reconnecting", true);
      setTimeout(connect, 1000);
    };
    ws.onerror = function () { /* onclose follows and reconnects */ };
  }
  connect();
})();
