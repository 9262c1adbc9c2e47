// ao4d/browser/page_common.js: the script every ao4d page shares (the slicing page, the image page and the
// result page that holds both). ao4d/browser/_page.py inlines it, once, as its own <script> before the
// page's script, so each page stays one self-contained file. It defines one global,
// `ao4dPage`: functions that take what they work on (the page's gl, canvas, state), small
// objects that keep their own state (the fragment writer, the fps clock, frames on demand), and
// page(spec), the life every page shares (state, URL, frames, message, window.ao4d, start-up).
"use strict";
const ao4dPage = (function () {
  // ------------------------------------------------------------------ values
  // degrees into (-180, 180] (ao4d.browser.viewer.full_state)
  function wrap(a) { a = ((a + 180) % 360 + 360) % 360 - 180; return a === -180 ? 180 : a + 0; }
  // a number as the fragment writes it: 4 decimals at most, no "-0"
  function fmt(x) { const s = String(+x.toFixed(4)); return s === "-0" ? "0" : s; }
  // a value that is not valid is left out with a console warning, never applied
  function ignored(k, v, why) { console.warn(`ao4d view: ignoring ${k}=${JSON.stringify(v)}: ${why || "not a valid value"}`); }

  // ------------------------------------------------------------------ the URL fragment
  // "#a=1&b=x%20y" -> [["a", "1"], ["b", "x y"]]; a part without "=" is skipped, one that does
  // not decode ("URI malformed": a stray % in a hand-edited fragment) is left out with a warning
  function fragmentPairs(text) {
    const out = [];
    const h = (text || "").replace(/^#/, "");
    if (!h) return out;
    for (const part of h.split("&")) {
      const i = part.indexOf("=");
      if (i < 0) continue;
      try { out.push([decodeURIComponent(part.slice(0, i)), decodeURIComponent(part.slice(i + 1))]); }
      catch (e) { console.warn(`ao4d view: ignoring ${JSON.stringify(part)} in the URL fragment: ${e.message}`); }
    }
    return out;
  }
  // the page's state in its URL: write() puts hashText() there (no history entry) when it
  // changed; follow(apply) applies a fragment the user edits (not the page's own writes)
  function hashWriter(hashText) {
    let last = "";
    return {
      write() {
        const h = hashText();
        if (h === location.hash || h === last) return;
        last = h;
        try { history.replaceState(null, "", h); } catch (e) { /* some contexts (srcdoc, file://) refuse */ }
      },
      mark() { last = hashText(); },
      follow(apply) { window.addEventListener("hashchange", () => { if (location.hash !== last) apply(location.hash); }); },
    };
  }

  // ------------------------------------------------------------------ data
  function b64bytes(text) {
    if (typeof Uint8Array.fromBase64 === "function") return Uint8Array.fromBase64(text.trim());
    const bin = atob(text.trim()), n = bin.length, out = new Uint8Array(n);
    for (let i = 0; i < n; i++) out[i] = bin.charCodeAt(i);
    return out;
  }
  const TYPED = { uint8: Uint8Array, uint32: Uint32Array, float32: Float32Array, float64: Float64Array };
  // one buffer of the page: base64 in the <script> of id meta.id, or served at meta.url;
  // deflated when meta.encoding says so; a typed array of meta.dtype (bytes without one)
  async function loadBlob(meta) {
    let bytes;
    if (meta.url) {
      const response = await fetch(meta.url);
      if (!response.ok) throw new Error("cannot fetch " + meta.url + ": " + response.status);
      bytes = new Uint8Array(await response.arrayBuffer());
    } else {
      bytes = b64bytes(document.getElementById(meta.id).textContent);
    }
    if (meta.encoding === "deflate") {
      if (typeof DecompressionStream !== "function") throw new Error("this browser lacks DecompressionStream; write the page with compress=False");
      const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
      bytes = new Uint8Array(await new Response(stream).arrayBuffer());
    }
    if (bytes.byteLength !== meta.nbytes) throw new Error("buffer has " + bytes.byteLength + " bytes, expected " + meta.nbytes);
    const type = TYPED[meta.dtype || "uint8"];
    if (type === Uint8Array) return bytes;
    const buffer = bytes.byteOffset === 0 && bytes.byteLength === bytes.buffer.byteLength ? bytes.buffer : bytes.slice().buffer;
    return new type(buffer);
  }

  // ------------------------------------------------------------------ camera (ao4d.browser.viewer.camera)
  const dot3 = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm3 = (a) => { const l = Math.hypot(a[0], a[1], a[2]); return [a[0] / l, a[1] / l, a[2] / l]; };
  // the orbit camera about the scene's centre, the origin of the page's coordinates: `view` is
  // the scene's camera ({half_fov_deg, margin}), `radius` the ball it frames; `scale` is pixels
  // per unit of the image plane at distance 1
  function orbitCamera(view, radius, az, el, zoom, width, height) {
    const half = view.half_fov_deg * Math.PI / 180;
    const a = az * Math.PI / 180, e = el * Math.PI / 180;
    const back = [Math.cos(e) * Math.sin(a), Math.sin(e), Math.cos(e) * Math.cos(a)];
    const up = [-Math.sin(e) * Math.sin(a), Math.cos(e), -Math.sin(e) * Math.cos(a)];
    const fwd = [-back[0], -back[1], -back[2]];
    const right = cross(fwd, up);
    const dist = view.margin * radius / Math.sin(half);
    const eye = back.map((b) => dist * b);
    const scale = Math.min(width, height) / 2 / (Math.tan(half) / zoom);
    return { back, up, fwd, right, eye, dist, scale };
  }

  // ------------------------------------------------------------------ WebGL
  // the first lines of every shader: GLSL ES 3.00, high precision
  const GLSL = "#version 300 es\nprecision highp float;\nprecision highp int;\n";
  // a program and its uniforms' locations (an array uniform under its name without "[0]")
  function compile(gl, vsText, fsText) {
    const prog = gl.createProgram();
    for (const [type, text] of [[gl.VERTEX_SHADER, vsText], [gl.FRAGMENT_SHADER, fsText]]) {
      const sh = gl.createShader(type);
      gl.shaderSource(sh, text);
      gl.compileShader(sh);
      if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(sh));
      gl.attachShader(prog, sh);
    }
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(prog));
    const uniforms = {};
    const n = gl.getProgramParameter(prog, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) {
      const info = gl.getActiveUniform(prog, i), name = info.name.replace(/\[0\]$/, "");
      uniforms[name] = gl.getUniformLocation(prog, info.name);
    }
    return { prog, uniforms };
  }
  // WebGL errors are reported, not silent (checked where a sync costs nothing extra)
  function checkGL(gl, where) {
    const err = gl.getError();
    if (err !== gl.NO_ERROR) console.error("ao4d view: WebGL error 0x" + err.toString(16) + " in " + where);
  }
  function rendererName(gl) {
    let r = gl.getParameter(gl.RENDERER) || "";
    if (/^webkit webgl$/i.test(r)) {  // Chromium masks it; Firefox does not (and warns on the extension)
      const ext = gl.getExtension("WEBGL_debug_renderer_info");
      if (ext) r = gl.getParameter(ext.UNMASKED_RENDERER_WEBGL);
    }
    return r;
  }
  // the canvas' drawing buffer at its CSS size times the device's pixel ratio
  function fitCanvas(canvas) {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  }
  // the canvas just drawn, read back: RGBA rows from the top, base64 (alpha 0 = background)
  function readCanvas(gl, canvas) {
    checkGL(gl, "capture");
    const w = canvas.width, h = canvas.height, px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const flipped = new Uint8Array(w * h * 4);
    for (let y = 0; y < h; y++) flipped.set(px.subarray((h - 1 - y) * w * 4, (h - y) * w * 4), y * w * 4);
    let bin = "";
    for (let i = 0; i < flipped.length; i += 0x8000) bin += String.fromCharCode.apply(null, flipped.subarray(i, i + 0x8000));
    return { width: w, height: h, rgba: btoa(bin) };
  }
  // the canvas just drawn over the page's background colour bg ([r, g, b]), as a 2D canvas
  function flatten(canvas, bg) {
    const c2 = document.createElement("canvas");
    c2.width = canvas.width; c2.height = canvas.height;
    const ctx = c2.getContext("2d");
    ctx.fillStyle = `rgb(${bg[0]},${bg[1]},${bg[2]})`;
    ctx.fillRect(0, 0, c2.width, c2.height);
    ctx.drawImage(canvas, 0, 0);
    return c2;
  }
  // download a canvas as a PNG file
  function savePNG(canvas, name) {
    canvas.toBlob((blob) => {
      const a = document.createElement("a");
      a.href = URL.createObjectURL(blob);
      a.download = name;
      document.body.appendChild(a); a.click(); a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 2000);
    }, "image/png");
  }
  // frames drawn back to back while state[key] takes the values at(i) (restored afterwards), each
  // waiting for the GPU with a 1-pixel read: throughput, no vsync
  function sweepFrames(gl, draw, state, key, frames, at) {
    const saved = state[key], px = new Uint8Array(4);
    draw(); gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const t0 = performance.now();
    for (let i = 0; i < frames; i++) {
      state[key] = at(i);
      draw();
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    }
    const ms = (performance.now() - t0) / frames;
    checkGL(gl, "bench");
    state[key] = saved;
    return { frames, ms_per_frame: ms, fps: 1000 / ms };
  }

  // ------------------------------------------------------------------ frames
  // frames per second over the last second of back-to-back frames (a pause restarts it)
  function frameClock() {
    const times = [];
    return {
      fps: 0,
      ms: 0,
      tick(t) {
        if (times.length && t - times[times.length - 1] > 500) times.length = 0;
        times.push(t);
        while (times.length > 2 && t - times[0] > 1000) times.shift();
        if (times.length < 2) return;
        const span = times[times.length - 1] - times[0];
        if (span > 0) { this.fps = 1000 * (times.length - 1) / span; this.ms = span / (times.length - 1); }
      },
      reset() { times.length = 0; },
    };
  }
  // frames on demand: request() asks for one; none is drawn while the GPU still works on the
  // last one (a fence), so slow renderers never queue frames and the fps shown are frames
  // actually rendered. motion(t), when given, moves the scene before a frame and returns true
  // while it moves (frames keep coming); drawn() runs after each frame.
  function frameLoop(gl, clock, draw, drawn, motion) {
    let fence = null, dirty = true, pending = false, moving = false;
    function busy() {
      if (!fence) return false;
      if (gl.getSyncParameter(fence, gl.SYNC_STATUS) !== gl.SIGNALED) return true;
      gl.deleteSync(fence);
      fence = null;
      return false;
    }
    function frame(t) {
      pending = false;
      if ((dirty || moving) && busy()) { pending = true; requestAnimationFrame(frame); return; }
      moving = motion ? motion(t) : false;
      if (!dirty && !moving) return;
      draw();
      fence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
      gl.flush();
      dirty = false;
      clock.tick(t);
      drawn();
      if (moving) { pending = true; requestAnimationFrame(frame); }
    }
    return { request() { dirty = true; if (!pending) { pending = true; requestAnimationFrame(frame); } } };
  }
  // fn() at most every ms milliseconds, soon after a call (census, message, URL: not every frame)
  function throttled(fn, ms) {
    let timer = null, last = 0;
    return () => {
      if (timer !== null) return;
      const wait = Math.max(0, ms - (performance.now() - last));
      timer = setTimeout(() => { timer = null; last = performance.now(); fn(); }, wait);
    };
  }

  // ------------------------------------------------------------------ panel and input
  function addSlider(parent, key, min, max, step) {
    const row = document.createElement("div");
    row.className = "row";
    row.innerHTML = `<label for="in-${key}">${key}</label><input id="in-${key}" type="range" min="${min}" max="${max}" step="${step}"><span class="val" id="val-${key}"></span>`;
    parent.appendChild(row);
  }
  // the sliders of these keys set the state (zoom's slider is log10 of the zoom)
  function bindSliders(keys, setState) {
    for (const k of keys) {
      const input = document.getElementById("in-" + k);
      input.addEventListener("input", () => { const x = Number(input.value); setState({ [k]: k === "zoom" ? Math.pow(10, x) : x }); });
    }
  }
  // a slider and its number shown with `digits` decimals (zoom: log10 on the slider, 2 decimals)
  function setSlider(key, value, digits) {
    const input = document.getElementById("in-" + key);
    if (!input) return;
    input.value = key === "zoom" ? Math.log10(value) : value;
    document.getElementById("val-" + key).textContent = value.toFixed(key === "zoom" ? 2 : digits);
  }
  // mouse on the canvas: drag orbits (shift-drag: shiftDrag(dx, dy), when given), wheel zooms;
  // the canvas redraws when its size changes
  function bindOrbit(canvas, state, setState, redraw, shiftDrag) {
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY }; canvas.setPointerCapture(e.pointerId); canvas.classList.add("dragging"); canvas.focus(); });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      drag = { x: e.clientX, y: e.clientY };
      if (e.shiftKey && shiftDrag) shiftDrag(dx, dy);
      else setState({ az: state.az - 0.4 * dx, el: state.el + 0.4 * dy });
    });
    const endDrag = () => { drag = null; canvas.classList.remove("dragging"); };
    canvas.addEventListener("pointerup", endDrag);
    canvas.addEventListener("pointercancel", endDrag);
    canvas.addEventListener("wheel", (e) => { e.preventDefault(); setState({ zoom: state.zoom * Math.exp(-0.0015 * e.deltaY) }); }, { passive: false });
    new ResizeObserver(() => redraw()).observe(canvas);
  }
  // keys (not while a slider or a menu has the focus): arrows orbit, + - zoom, p PNG, r reset,
  // h hides the panel; the page's own keys first: pageKey(e) returns true for a key it handled
  function bindKeys(state, setState, { png, redraw, pageKey }) {
    window.addEventListener("keydown", (e) => {
      const t = e.target;
      if ((t instanceof HTMLInputElement && t.type === "range") || t instanceof HTMLSelectElement) return;
      if (e.ctrlKey || e.metaKey || e.altKey) return;
      if (pageKey && pageKey(e)) { e.preventDefault(); return; }
      let handled = true;
      switch (e.key) {
        case "ArrowLeft": setState({ az: state.az + 5 }); break;
        case "ArrowRight": setState({ az: state.az - 5 }); break;
        case "ArrowUp": setState({ el: state.el + 5 }); break;
        case "ArrowDown": setState({ el: state.el - 5 }); break;
        case "+": case "=": setState({ zoom: state.zoom * 1.1 }); break;
        case "-": case "_": setState({ zoom: state.zoom / 1.1 }); break;
        case "p": png(); break;
        case "r": document.getElementById("reset").click(); break;
        case "h": document.getElementById("panel").classList.toggle("closed"); redraw(); break;
        default: handled = false;
      }
      if (handled) e.preventDefault();
    });
  }
  // the line over the canvas: the error, "loading...", or what detail() says ("" for nothing)
  function showMessage(api, detail) {
    const text = api.error || (api.ready ? detail() : "loading\u2026");
    const box = document.getElementById("message");
    box.innerHTML = "";
    if (text) { const span = document.createElement("span"); span.textContent = text; box.appendChild(span); }
  }
  // the sliders of the 3D camera (az, el, zoom: zoom's slider is log10 of the zoom)
  function cameraSliders(parent) {
    addSlider(parent, "az", -180, 180, 0.5);
    addSlider(parent, "el", -90, 90, 0.5);
    addSlider(parent, "zoom", -1, 1.3, 0.01);
  }

  // ------------------------------------------------------------------ the page
  // what every page does with what it brings (spec): its state set (clean(), then the controls,
  // sync(), a frame, and the URL soon after, with idle()), written to the URL fragment
  // (hashText()) and read back from it (parseHash()), frames on demand (draw(), drawn(),
  // motion(t)), the message over the canvas (error, "loading...", or message()), PNGs over
  // the background bg (pngName), and window.ao4d's setState, state, hash, capture and png.
  // run() starts the page: the fragment's state, then spec.steps (the panel, WebGL: setting
  // the page's gl, spec.gl() reads it; the buffers), then frames; an error stops it, shown.
  function page(spec) {
    const { api, state, canvas } = spec;
    const clock = frameClock();
    const hash = hashWriter(spec.hashText);
    let gl = null, loop = null;
    const scheduleIdle = throttled(() => { hash.write(); spec.idle(); }, 250);
    function requestRender() { if (loop) loop.request(); }
    function setState(partial, quiet) {
      Object.assign(state, spec.clean(partial));
      spec.sync();
      requestRender();
      if (!quiet) scheduleIdle();
      return spec.snapshot();
    }
    function updateMessage() { showMessage(api, spec.message); }
    function composite() { spec.draw(); return flatten(canvas, spec.bg); }
    function drawn() {
      if (!api.ready) {
        checkGL(gl, "first frame");
        api.ready = true;
        document.documentElement.dataset.ready = "1";
        updateMessage();
      }
      spec.drawn();
    }
    async function run() {
      try {
        Object.assign(state, spec.parseHash(location.hash));
        hash.follow((text) => setState(spec.parseHash(text)));
        for (const step of spec.steps) await step();
        gl = spec.gl();
        hash.mark();
        loop = frameLoop(gl, clock, spec.draw, drawn, spec.motion);
        loop.request();
      } catch (err) {
        api.error = String(err && err.message || err);
        updateMessage();
        console.error("ao4d view: " + api.error);
      }
    }
    api.setState = (partial) => setState(partial || {});
    api.state = () => spec.snapshot();
    api.hash = () => spec.hashText();
    // draw now and read the canvas back: RGBA rows from the top, base64 (alpha 0 = background)
    api.capture = () => { spec.draw(); return readCanvas(gl, canvas); };
    api.png = () => composite().toDataURL("image/png");
    return { clock, setState, requestRender, scheduleIdle, updateMessage, run, png: () => savePNG(composite(), spec.pngName) };
  }

  return Object.freeze({
    GLSL, wrap, fmt, ignored, fragmentPairs, hashWriter, b64bytes, loadBlob, dot3, norm3, orbitCamera,
    compile, rendererName, fitCanvas, sweepFrames, addSlider, bindSliders, setSlider, cameraSliders,
    bindOrbit, bindKeys, page,
  });
})();
