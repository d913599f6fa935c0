// kalos view: the lightmap of a .glb from `kalos bake --lightmap`, and
// the lightmap of a bake as it runs (`kalos bake --lightmap --view`).
//
// A GLTFLoader plugin for the `MOZ_lightmap` material extension (Mozilla
// Hubs'; see docs/lightmaps.md): the texture it names becomes three.js's
// `lightMap` on uv channel 1 (TEXCOORD_1), scaled by its `intensity`. The
// texture's 16-bit PNG is decoded here into a half-float texture (the
// browser's own decoder keeps 8 bits). The standard error named by the extension's
// `extras.kalosStdError` is loaded the same way, for the error map.

import * as THREE from "three";

// Decodes a PNG (8- or 16-bit, grey, grey+alpha, RGB or RGBA, not
// interlaced) to { width, height, data }: RGBA floats in [0, 1], top row
// first. The browser's own decoder would give 8 bits per channel; the
// lightmap's PNG has 16.
export async function decodePNG(buffer) {
  const b = new Uint8Array(buffer);
  const dv = new DataView(buffer instanceof ArrayBuffer ? buffer : b.buffer);
  let p = 8, width = 0, height = 0, depth = 8, ctype = 2;
  const idat = [];
  while (p < b.length) {
    const n = dv.getUint32(p);
    const kind = String.fromCharCode(...b.subarray(p + 4, p + 8));
    const body = b.subarray(p + 8, p + 8 + n);
    if (kind === "IHDR") {
      const h = new DataView(body.buffer, body.byteOffset, body.length);
      width = h.getUint32(0); height = h.getUint32(4); depth = body[8]; ctype = body[9];
      if (body[12] !== 0) throw new Error("interlaced PNG");
    } else if (kind === "IDAT") {
      idat.push(body);
    }
    p += 12 + n;
  }
  const channels = { 0: 1, 2: 3, 4: 2, 6: 4 }[ctype];
  if (!channels || (depth !== 8 && depth !== 16)) throw new Error("unsupported PNG");
  const stream = new Blob(idat).stream().pipeThrough(new DecompressionStream("deflate"));
  const raw = new Uint8Array(await new Response(stream).arrayBuffer());
  const bpp = channels * depth / 8, stride = width * bpp;
  const data = new Float32Array(width * height * 4);
  let prev = new Uint8Array(stride);
  for (let y = 0; y < height; y++) {
    const f = raw[y * (stride + 1)];
    const line = raw.slice(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let i = 0; i < stride; i++) {
      const a = i >= bpp ? line[i - bpp] : 0, up = prev[i], c = i >= bpp ? prev[i - bpp] : 0;
      let add = 0;
      if (f === 1) add = a;
      else if (f === 2) add = up;
      else if (f === 3) add = (a + up) >> 1;
      else if (f === 4) {
        const q = a + up - c, pa = Math.abs(q - a), pb = Math.abs(q - up), pc = Math.abs(q - c);
        add = pa <= pb && pa <= pc ? a : pb <= pc ? up : c;
      }
      line[i] = (line[i] + add) & 255;
    }
    const max = depth === 16 ? 65535 : 255;
    for (let x = 0; x < width; x++) {
      const v = (k) => depth === 16
        ? (line[(x * channels + k) * 2] << 8 | line[(x * channels + k) * 2 + 1]) / max
        : line[x * channels + k] / max;
      const o = (y * width + x) * 4;
      const g = channels < 3;
      data[o] = v(0);
      data[o + 1] = g ? v(0) : v(1);
      data[o + 2] = g ? v(0) : v(2);
      data[o + 3] = 1;
    }
    prev = line;
  }
  return { width, height, data };
}

// A texture of the .glb as a linear lightmap: its PNG decoded here (all 16
// bits) into a half-float texture; any other image through GLTFLoader,
// read as linear.
async function lightmapTexture(parser, index) {
  const def = parser.json.textures[index];
  const img = parser.json.images[def.source];
  let t;
  if (img.mimeType === "image/png" && img.bufferView !== undefined) {
    const bytes = await parser.getDependency("bufferView", img.bufferView);
    const { width, height, data } = await decodePNG(bytes);
    const half = new Uint16Array(data.length);
    for (let i = 0; i < data.length; i++) half[i] = THREE.DataUtils.toHalfFloat(data[i]);
    t = new THREE.DataTexture(half, width, height, THREE.RGBAFormat, THREE.HalfFloatType);
    t.needsUpdate = true;
  } else {
    t = (await parser.getDependency("texture", index)).clone();
  }
  // glTF's uv (0, 0) is the image's first row, as GLTFLoader's textures
  t.flipY = false;
  t.colorSpace = THREE.NoColorSpace;
  t.magFilter = THREE.LinearFilter;
  t.minFilter = THREE.LinearFilter;
  t.generateMipmaps = false;
  t.wrapS = t.wrapT = THREE.ClampToEdgeWrapping;
  return t;
}

// The plugin: fills `lightMap`, `lightMapIntensity`; keeps, by material
// index, the extension's intensity and its error texture in `found`.
export class MozLightmap {
  constructor(parser, found) {
    this.parser = parser;
    this.name = "MOZ_lightmap";
    this.found = found;
  }

  async extendMaterialParams(materialIndex, params) {
    const def = this.parser.json.materials[materialIndex];
    const ext = def.extensions && def.extensions.MOZ_lightmap;
    if (!ext) return;
    const tex = await lightmapTexture(this.parser, ext.index);
    tex.channel = ext.texCoord === undefined ? 1 : ext.texCoord;
    params.lightMap = tex;
    params.lightMapIntensity = ext.intensity === undefined ? 1 : ext.intensity;
    const e = ext.extras && ext.extras.kalosStdError;
    const err = e ? await lightmapTexture(this.parser, e.index) : null;
    const entry = { intensity: params.lightMapIntensity, lightMap: tex, err };
    this.found.set(materialIndex, entry);
    entries.push(entry);
  }
}

// Every lightmap the plugin made, one per material: a live bake swaps
// their pixels in place.
const entries = [];

// False colour of the relative standard error σ/E on uv 1: blue at 0,
// through green and yellow, red at `top` (10 %) and above; black where
// the lightmap is black.
export function errorMaterial(lightMap, err) {
  return new THREE.ShaderMaterial({
    uniforms: { lm: { value: lightMap }, err: { value: err }, top: { value: 0.1 } },
    vertexShader: `
      attribute vec2 uv1;
      varying vec2 vUv1;
      void main() {
        vUv1 = uv1;
        gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0);
      }`,
    fragmentShader: `
      uniform sampler2D lm;
      uniform sampler2D err;
      uniform float top;
      varying vec2 vUv1;
      void main() {
        vec3 e = texture2D(lm, vUv1).rgb;
        vec3 s = texture2D(err, vUv1).rgb;
        float m = max(max(e.r, e.g), e.b);
        if (m <= 0.0) { gl_FragColor = vec4(0.0, 0.0, 0.0, 1.0); return; }
        float t = clamp(max(max(s.r, s.g), s.b) / m / top, 0.0, 1.0);
        vec3 c = t < 0.5 ? mix(vec3(0.0, 0.2, 1.0), vec3(0.0, 0.9, 0.2), t * 2.0)
                         : mix(vec3(1.0, 0.9, 0.0), vec3(1.0, 0.0, 0.0), t * 2.0 - 1.0);
        gl_FragColor = vec4(c, 1.0);
      }`,
  });
}

// `kalos bake --lightmap --view`: the asset once the bake has made its uv
// set (its atlas black), then each new atlas swapped into the lightmap
// textures in place: no reload, the camera stays, the exposure and the
// error map apply to it. The panel shows the bake's phase and particles.
//
// The server sends an atlas (`/image`) as "KLM1", width and height (u32),
// the scale S (f32: the .glb's `intensity` for it), then E/S and σ/S as
// RGB f32 per texel, top row first, clipped to [0, 1] as the .glb's PNGs
// are; all little-endian.
export async function showLive($) {
  $("live-controls").hidden = false;
  const k = window.kalos;
  Object.assign(k, { atlasVersion: 0, atlasSums: [], atlasParticles: 0, done: false });
  let st = await status($);
  while (st && !st.asset) {
    await sleep(300);
    st = await status($);
  }
  if (!st) return;
  await (await import("/view/mesh.js")).show($);
  let version = 0;
  for (;;) {
    if (st.version !== version) {
      const r = await fetch("/image");
      if (r.ok) {
        apply($, decodeAtlas(await r.arrayBuffer()));
        version = st.version;
        k.atlasVersion++;
        k.atlasParticles = st.bake.atlas_particles;
      }
    }
    k.done = st.done && version === st.version;
    if (k.done) return;
    await sleep(500);
    st = await status($);
    if (!st) return;
  }
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

const count = (n) => n >= 1e6 ? `${(n / 1e6).toFixed(2)} M` : n >= 1e3 ? `${(n / 1e3).toFixed(1)} k` : `${n}`;

// The bake's progress, shown in the panel; null once kalos has exited.
async function status($) {
  let st;
  try {
    st = await (await fetch("/status")).json();
  } catch (e) {
    $("progress").textContent += "\n(kalos has exited)";
    return null;
  }
  const b = st.bake || {};
  const lines = [];
  if (st.done) {
    lines.push(`finished: ${count(b.particles)} particles`, "the .glb is written;",
      "Ctrl-C in the terminal ends kalos");
  } else {
    let line = st.phase || "starting";
    if (b.total > 0 && st.phase !== "estimating a preview") {
      line += ` ${Math.floor(100 * b.done / b.total)} %`;
    }
    lines.push(line);
    if (b.particles_total) {
      lines.push(`particles ${count(b.particles)} of ${count(b.particles_total)}`);
    }
  }
  lines.push(b.atlas_particles
    ? `lightmap from ${count(b.atlas_particles)} particles`
    : st.asset ? "lightmap: black until the first preview" : "waiting for the asset");
  if (b.previews) lines.push(`previews ${b.previews}, ${b.preview_seconds.toFixed(1)} s in all`);
  lines.push(`elapsed ${st.elapsed.toFixed(1)} s`);
  $("progress").textContent = lines.join("\n");
  window.kalos.phase = st.phase;
  window.kalos.particles = b.particles;
  return st;
}

function decodeAtlas(buf) {
  const dv = new DataView(buf);
  if (String.fromCharCode(...new Uint8Array(buf, 0, 4)) !== "KLM1") {
    throw new Error("the server sent no atlas");
  }
  const w = dv.getUint32(4, true), h = dv.getUint32(8, true), scale = dv.getFloat32(12, true);
  const n = w * h * 3;
  return {
    w, h, scale,
    irradiance: new Float32Array(buf, 16, n),
    error: new Float32Array(buf, 16 + 4 * n, n),
  };
}

// An atlas's RGB floats as the RGBA half floats of the lightmap textures.
function halfRGBA(rgb, w, h) {
  const out = new Uint16Array(w * h * 4);
  const one = THREE.DataUtils.toHalfFloat(1);
  for (let i = 0, j = 0; i < w * h; i++, j += 3) {
    out[4 * i] = THREE.DataUtils.toHalfFloat(rgb[j]);
    out[4 * i + 1] = THREE.DataUtils.toHalfFloat(rgb[j + 1]);
    out[4 * i + 2] = THREE.DataUtils.toHalfFloat(rgb[j + 2]);
    out[4 * i + 3] = one;
  }
  return out;
}

// Swaps `atlas` into every lightmap texture (and error texture) of the
// asset's atlas size, sets their intensity, and redraws at the exposure.
function apply($, atlas) {
  const { w, h, scale } = atlas;
  const irradiance = halfRGBA(atlas.irradiance, w, h), error = halfRGBA(atlas.error, w, h);
  let sum = 0;
  for (const v of atlas.irradiance) sum += v;
  for (const e of entries) {
    const img = e.lightMap.image;
    if (!img || img.width !== w || img.height !== h) continue;
    img.data = irradiance;
    e.lightMap.needsUpdate = true;
    if (e.err && e.err.image.width === w && e.err.image.height === h) {
      e.err.image.data = error;
      e.err.needsUpdate = true;
    }
    e.intensity = scale;
  }
  window.kalos.atlasSums.push(sum * scale);
  // the exposure multiplies each lightmap's intensity, and redraws
  window.kalos.setExposure(Number($("exposure").value));
}
