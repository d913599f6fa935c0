// kalos view: a linear HDR image (EXR, PFM, HDR), or a render as it
// converges (`kalos render --view`).
//
// The server sends the pixels as linear floats (`/image`: "KIMG", width and
// height as u32, then RGB f32, all little-endian, top row first); the page
// tone-maps them as `kalos render` writes a PNG: 2^exposure, the curve,
// then the sRGB transfer function.

const $canvas = document.createElement("canvas");

// Luminance as kalos computes it (Rec. 709), in cd/m² with Radiance's
// luminous efficacy of 179 lm/W, as its falsecolor reports.
const EFFICACY = 179;
const luminance = (r, g, b) => 0.2126 * r + 0.7152 * g + 0.0722 * b;

// A ramp in the manner of Radiance's falsecolor: dark purple for the lowest
// values, through blue, green and yellow, to red and magenta at the top.
const RAMP = [
  [0.18, 0.0, 0.35], [0.0, 0.1, 0.75], [0.0, 0.55, 0.85], [0.0, 0.7, 0.3],
  [0.65, 0.85, 0.0], [1.0, 0.75, 0.0], [1.0, 0.3, 0.0], [0.9, 0.0, 0.45],
];
const BANDS = 8;

function ramp(t) {
  t = Math.min(Math.max(t, 0), 1) * (RAMP.length - 1);
  const i = Math.min(Math.floor(t), RAMP.length - 2);
  const f = t - i;
  return RAMP[i].map((a, k) => a + (RAMP[i + 1][k] - a) * f);
}

const TONEMAPS = {
  clamp: (x) => x,
  reinhard: (x) => x / (1 + x),
  aces: (x) => (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14),
};

function srgb8(c) {
  c = Math.min(Math.max(c, 0), 1);
  const v = c <= 0.0031308 ? 12.92 * c : 1.055 * Math.pow(c, 1 / 2.4) - 0.055;
  return Math.round(v * 255);
}

function decode(buf) {
  const dv = new DataView(buf);
  const magic = String.fromCharCode(...new Uint8Array(buf, 0, 4));
  if (magic !== "KIMG") throw new Error("the server sent no image");
  const w = dv.getUint32(4, true), h = dv.getUint32(8, true);
  const px = new Float32Array(buf.slice(12, 12 + w * h * 12));
  return { w, h, px };
}

export async function show($, live) {
  $("image-controls").hidden = false;
  $("live-controls").hidden = !live;
  const stage = $("stage");
  stage.appendChild($canvas);
  $canvas.style.imageRendering = "pixelated";
  let img = null;

  // the false-colour scale: [0, max] in cd/m², linear or over 2 decades
  function scaleOf() {
    const max = Math.max(Number($("fc-max").value) || 1000, 1e-12);
    const log = $("fc-log").checked;
    const t = (l) => log ? 1 + Math.log10(Math.max(l, 1e-30) / max) / 2 : l / max;
    const value = (t) => log ? max * Math.pow(10, 2 * (t - 1)) : t * max;
    return { t, value };
  }

  function draw() {
    if (!img) return;
    const { w, h, px } = img;
    if ($canvas.width !== w || $canvas.height !== h) {
      $canvas.width = w;
      $canvas.height = h;
      $canvas.style.width = `${w}px`;
      $canvas.style.height = `${h}px`;
    }
    const ctx = $canvas.getContext("2d");
    const out = ctx.createImageData(w, h);
    const e = Math.pow(2, Number($("exposure").value));
    const curve = TONEMAPS[$("tonemap").value];
    const falsecolor = $("falsecolor").checked;
    const scale = scaleOf();
    for (let i = 0; i < w * h; i++) {
      const r = px[3 * i], g = px[3 * i + 1], b = px[3 * i + 2];
      let c;
      if (falsecolor) {
        c = ramp(scale.t(EFFICACY * luminance(r, g, b))).map(srgb8);
      } else {
        c = [r, g, b].map((v) => srgb8(curve(Math.max(v * e, 0))));
      }
      out.data[4 * i] = c[0];
      out.data[4 * i + 1] = c[1];
      out.data[4 * i + 2] = c[2];
      out.data[4 * i + 3] = 255;
    }
    ctx.putImageData(out, 0, 0);
    legend();
  }

  function legend() {
    const el = $("legend");
    el.style.display = $("falsecolor").checked ? "block" : "none";
    const scale = scaleOf();
    el.innerHTML = "";
    for (let k = BANDS - 1; k >= 0; k--) {
      const t = (k + 0.5) / BANDS;
      const c = ramp(t).map(srgb8);
      const row = document.createElement("div");
      row.innerHTML = `<span class="sw" style="background:rgb(${c})"></span>` +
        `${scale.value(k / BANDS).toPrecision(3)} – ${scale.value((k + 1) / BANDS).toPrecision(3)} cd/m²`;
      el.appendChild(row);
    }
  }

  // Pixel values under the pointer, in the file's own numbers
  $canvas.addEventListener("mousemove", (ev) => {
    if (!img) return;
    const rect = $canvas.getBoundingClientRect();
    const x = Math.floor((ev.clientX - rect.left) * img.w / rect.width);
    const y = Math.floor((ev.clientY - rect.top) * img.h / rect.height);
    if (x < 0 || y < 0 || x >= img.w || y >= img.h) return;
    const i = 3 * (y * img.w + x);
    const [r, g, b] = [img.px[i], img.px[i + 1], img.px[i + 2]];
    const l = EFFICACY * luminance(r, g, b);
    window.kalos.pixel = { x, y, r, g, b };
    $("pixel").textContent = `x ${x}  y ${y}\nR ${r.toPrecision(7)}\nG ${g.toPrecision(7)}\n` +
      `B ${b.toPrecision(7)}\nL ${l.toPrecision(4)} cd/m²`;
  });

  for (const id of ["exposure", "tonemap", "falsecolor", "fc-max", "fc-log"]) {
    $(id).addEventListener("input", () => {
      $("exposure-value").textContent = Number($("exposure").value).toFixed(1);
      draw();
    });
  }

  // The false-colour scale starts at the image's own range (its 99th
  // percentile of luminance, rounded up to 1, 2 or 5 × 10^k), since kalos's
  // images have no fixed exposure; Radiance's fixed 1000 cd/m² would leave
  // most renders in the lowest band. The user's value then stays.
  let scaled = false;
  function niceScale({ w, h, px }) {
    const step = Math.max(1, Math.floor((w * h) / 100000));
    const ls = [];
    for (let i = 0; i < w * h; i += step) {
      ls.push(EFFICACY * luminance(px[3 * i], px[3 * i + 1], px[3 * i + 2]));
    }
    ls.sort((a, b) => a - b);
    const p99 = ls[Math.min(ls.length - 1, Math.floor(ls.length * 0.99))];
    if (!(p99 > 0) || !isFinite(p99)) return 1000;
    const k = Math.pow(10, Math.floor(Math.log10(p99)));
    return [1, 2, 5, 10].map((m) => m * k).find((v) => v >= p99);
  }

  async function fetchImage() {
    const r = await fetch("/image");
    if (!r.ok) return false;
    img = decode(await r.arrayBuffer());
    let sum = 0;
    for (const v of img.px) sum += v;
    window.kalos.width = img.w;
    window.kalos.height = img.h;
    window.kalos.imageSum = sum;
    if (!scaled) {
      $("fc-max").value = niceScale(img);
      scaled = true;
    }
    draw();
    return true;
  }

  if (!live) {
    await fetchImage();
    window.kalos.ready = true;
    return;
  }

  // Live: poll the progress once a second, and the image when it changed.
  // The render goes on whether or not the page polls.
  let version = 0;
  const fmt = (s) => s >= 3600 ? `${(s / 3600).toFixed(1)} h` : s >= 60 ? `${(s / 60).toFixed(1)} min` : `${s.toFixed(1)} s`;
  async function poll() {
    let st;
    try {
      st = await (await fetch("/status")).json();
    } catch (e) {
      $("progress").textContent += "\n(kalos has exited)";
      return;
    }
    if (st.version !== version && await fetchImage()) version = st.version;
    window.kalos.passes = st.passes;
    window.kalos.version = version;
    window.kalos.done = st.done;
    window.kalos.ready = version > 0;
    const lines = [
      st.phase ? `setup: ${st.phase}` : `passes ${st.passes}`,
      `${(st.rays_per_s / 1e6).toFixed(2)} Mrays/s`,
      `elapsed ${fmt(st.elapsed)}`,
      st.done ? "finished" : st.time_left === null ? "time left: unknown" : `time left ${fmt(st.time_left)}`,
    ];
    if (st.curve.length) lines.push(`relMSE ${st.curve[st.curve.length - 1][1].toExponential(3)}`);
    $("progress").textContent = lines.join("\n");
    plot(st.curve);
    if (!st.done) setTimeout(poll, 1000);
  }
  poll();
}

// The convergence curve against --ref: relMSE over time, log-log.
function plot(curve) {
  const c = document.getElementById("curve");
  const pts = curve.filter(([t, e]) => t > 0 && e > 0);
  c.style.display = pts.length ? "block" : "none";
  if (!pts.length) return;
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height, m = 34;
  ctx.clearRect(0, 0, W, H);
  const xs = pts.map((p) => Math.log10(p[0])), ys = pts.map((p) => Math.log10(p[1]));
  const x0 = Math.min(...xs), x1 = Math.max(...xs, x0 + 1e-3);
  const y0 = Math.floor(Math.min(...ys)), y1 = Math.max(Math.ceil(Math.max(...ys)), y0 + 1);
  const X = (v) => m + (v - x0) / (x1 - x0) * (W - m - 6);
  const Y = (v) => H - 16 - (v - y0) / (y1 - y0) * (H - 24);
  ctx.strokeStyle = "#666";
  ctx.fillStyle = "#aaa";
  ctx.font = "10px sans-serif";
  for (let d = y0; d <= y1; d++) {
    ctx.beginPath(); ctx.moveTo(m, Y(d)); ctx.lineTo(W - 6, Y(d)); ctx.stroke();
    ctx.fillText(`1e${d}`, 2, Y(d) + 3);
  }
  ctx.fillText(`${pts[0][0].toFixed(1)} s`, m, H - 3);
  ctx.fillText(`${pts[pts.length - 1][0].toFixed(1)} s`, W - 50, H - 3);
  ctx.strokeStyle = "#4cf";
  ctx.beginPath();
  xs.forEach((x, i) => (i ? ctx.lineTo(X(x), Y(ys[i])) : ctx.moveTo(X(x), Y(ys[i]))));
  ctx.stroke();
}
