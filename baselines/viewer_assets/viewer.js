/* pcprep report: a small WebGL point viewer, self-contained (no library, no network).
 * Every <div class="pcv"> holds one scene: a <script type="application/json"> with
 * clouds (positions as base64 little-endian Float32, already centred and scaled to
 * [-1, 1]; colours as base64 RGB bytes). The scene's clouds share one canvas, one
 * panel each, and one camera: dragging any panel rotates every panel, the wheel zooms.
 * After its first frame a viewer writes data-drawn (lit pixels it read back) and
 * data-status on its element, so a test can tell it rendered. */
(function () {
  "use strict";
  var VS = "attribute vec3 p; attribute vec3 c; uniform mat4 m; uniform float s;" +
    "varying vec3 vc; void main(){ gl_Position = m * vec4(p, 1.0); gl_PointSize = s; vc = c; }";
  var FS = "precision mediump float; varying vec3 vc; void main(){" +
    " vec2 d = gl_PointCoord * 2.0 - 1.0; float r = dot(d, d); if (r > 1.0) discard;" +
    " float z = sqrt(1.0 - r); float l = 0.35 + 0.65 * max(0.0, dot(normalize(vec3(-d.x, d.y, z))," +
    " normalize(vec3(-0.4, 0.5, 0.77))));" +
    " gl_FragColor = vec4(vc * l, 1.0); }";

  function decode(b64, Type) {
    var bin = atob(b64), n = bin.length, u8 = new Uint8Array(n);
    for (var i = 0; i < n; i++) u8[i] = bin.charCodeAt(i);
    return Type === Uint8Array ? u8 : new Type(u8.buffer);
  }

  function shader(gl, type, src) {
    var s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  }

  function matrix(yaw, pitch, zoom, aspect) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    // rotation about the vertical axis, then about the horizontal one; column-major
    var r = [cy, sp * sy, -cp * sy, 0, 0, cp, sp, 0, sy, -sp * cy, cp * cy, 0, 0, 0, 0, 1];
    var sx = zoom / Math.max(aspect, 1), syy = zoom * Math.min(aspect, 1), sz = -0.5;
    return [r[0] * sx, r[1] * syy, r[2] * sz, 0, r[4] * sx, r[5] * syy, r[6] * sz, 0,
            r[8] * sx, r[9] * syy, r[10] * sz, 0, 0, 0, 0, 1];
  }

  function Viewer(el) {
    var data = JSON.parse(el.querySelector("script[type='application/json']").textContent);
    var clouds = data.clouds, n = clouds.length;
    var cols = Math.min(n, data.columns || 4), rows = Math.ceil(n / cols);
    var canvas = document.createElement("canvas");
    canvas.className = "pcv-canvas";
    el.appendChild(canvas);
    var labels = [];
    clouds.forEach(function (c) {
      var lab = document.createElement("div");
      lab.className = "pcv-label";
      lab.textContent = c.label + " (" + c.n + " points)";
      el.appendChild(lab);
      labels.push(lab);
    });
    var gl = canvas.getContext("webgl", {antialias: true, preserveDrawingBuffer: true});
    if (!gl) {
      el.setAttribute("data-status", "no WebGL");
      var msg = document.createElement("p");
      msg.textContent = "This browser offers no WebGL: the 3-D viewer cannot draw here.";
      el.appendChild(msg);
      return;
    }
    var prog = gl.createProgram();
    gl.attachShader(prog, shader(gl, gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl, gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
    var locP = gl.getAttribLocation(prog, "p"), locC = gl.getAttribLocation(prog, "c");
    var locM = gl.getUniformLocation(prog, "m"), locS = gl.getUniformLocation(prog, "s");
    var buffers = clouds.map(function (c) {
      var pb = gl.createBuffer(), cb = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, pb);
      gl.bufferData(gl.ARRAY_BUFFER, decode(c.positions, Float32Array), gl.STATIC_DRAW);
      gl.bindBuffer(gl.ARRAY_BUFFER, cb);
      gl.bufferData(gl.ARRAY_BUFFER, decode(c.colours, Uint8Array), gl.STATIC_DRAW);
      return {p: pb, c: cb, n: c.n};
    });
    var view = {yaw: data.yaw || -0.6, pitch: data.pitch || 0.45, zoom: 0.95};
    var size = data.point_size || 2.5;

    function layout() {
      var w = el.clientWidth || 800, cw = Math.floor(w / cols), ch = Math.round(cw * 0.8);
      var dpr = window.devicePixelRatio || 1;
      canvas.style.width = (cw * cols) + "px";
      canvas.style.height = (ch * rows) + "px";
      canvas.width = Math.round(cw * cols * dpr);
      canvas.height = Math.round(ch * rows * dpr);
      labels.forEach(function (lab, i) {
        lab.style.left = ((i % cols) * cw + 6) + "px";
        lab.style.top = (Math.floor(i / cols) * ch + 4) + "px";
      });
      return {cw: cw * dpr, ch: ch * dpr, dpr: dpr};
    }
    var geo = layout();

    function draw() {
      gl.enable(gl.DEPTH_TEST);
      gl.enable(gl.SCISSOR_TEST);
      gl.useProgram(prog);
      for (var i = 0; i < n; i++) {
        var x = (i % cols) * geo.cw, y = canvas.height - (Math.floor(i / cols) + 1) * geo.ch;
        gl.viewport(x, y, geo.cw, geo.ch);
        gl.scissor(x, y, geo.cw, geo.ch);
        gl.clearColor(1, 1, 1, 1);
        gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
        gl.uniformMatrix4fv(locM, false, new Float32Array(
          matrix(view.yaw, view.pitch, view.zoom, geo.cw / geo.ch)));
        gl.uniform1f(locS, size * geo.dpr * view.zoom);
        gl.bindBuffer(gl.ARRAY_BUFFER, buffers[i].p);
        gl.enableVertexAttribArray(locP);
        gl.vertexAttribPointer(locP, 3, gl.FLOAT, false, 0, 0);
        gl.bindBuffer(gl.ARRAY_BUFFER, buffers[i].c);
        gl.enableVertexAttribArray(locC);
        gl.vertexAttribPointer(locC, 3, gl.UNSIGNED_BYTE, true, 0, 0);
        gl.drawArrays(gl.POINTS, 0, buffers[i].n);
      }
    }

    function lit() {
      // how many pixels of the first panel differ from the white background
      var w = Math.floor(geo.cw), h = Math.floor(geo.ch), px = new Uint8Array(w * h * 4), k = 0;
      gl.readPixels(0, canvas.height - h, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
      for (var i = 0; i < px.length; i += 4) if (px[i] < 250 || px[i + 1] < 250 || px[i + 2] < 250) k++;
      return k;
    }

    var drag = null;
    canvas.addEventListener("pointerdown", function (e) {
      drag = {x: e.clientX, y: e.clientY};
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", function (e) {
      if (!drag) return;
      view.yaw += (e.clientX - drag.x) * 0.01;
      view.pitch = Math.max(-1.55, Math.min(1.55, view.pitch + (e.clientY - drag.y) * 0.01));
      drag = {x: e.clientX, y: e.clientY};
      requestAnimationFrame(draw);
    });
    canvas.addEventListener("pointerup", function () { drag = null; });
    canvas.addEventListener("wheel", function (e) {
      e.preventDefault();
      view.zoom = Math.max(0.3, Math.min(8, view.zoom * Math.exp(-e.deltaY * 0.001)));
      requestAnimationFrame(draw);
    }, {passive: false});
    window.addEventListener("resize", function () { geo = layout(); draw(); });
    draw();
    el.setAttribute("data-drawn", String(lit()));
    el.setAttribute("data-status", "drawn");
  }

  function start() {
    var els = document.querySelectorAll("div.pcv");
    for (var i = 0; i < els.length; i++) {
      try { Viewer(els[i]); } catch (err) {
        els[i].setAttribute("data-status", "error: " + err.message);
        throw err;
      }
    }
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", start);
  else start();
})();
