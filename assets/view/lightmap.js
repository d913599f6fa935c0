// kalos view: the lightmap of a .glb from `kalos bake --lightmap`.
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
    this.found.set(materialIndex, { intensity: params.lightMapIntensity, lightMap: tex, err });
  }
}

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
