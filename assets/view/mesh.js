// kalos view: a baked display mesh (.glb from `kalos bake`) in 3D.
//
// The lit surfaces carry `_RADIANCE` (linear W/(m²·sr), which three.js's
// GLTFLoader names `_radiance`); they are drawn from it, scaled by
// 2^exposure, unlit, and written to the sRGB canvas by three.js, so that at
// exposure 0 a pixel shows what `kalos render --tonemap clamp` writes for the
// same radiance. COLOR_0 (clamped to the bake's white point) is not used:
// it cannot be exposed down.
//
// A lightmapped .glb (`kalos bake --lightmap`, `MOZ_lightmap` materials) is
// shown with its own materials and textures and its lightmap on uv 1
// (lightmap.js), in a scene with no other light (the asset's lamps are
// switched off: the lightmap holds their light): a diffuse surface of
// albedo R shows R·E/π, its radiance, scaled by 2^exposure through the
// lightmap's intensity (and emitters' emissive intensity).

import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { MozLightmap, errorMaterial } from "/view/lightmap.js";

export async function show($) {
  $("mesh-controls").hidden = false;
  const stage = $("stage");
  const renderer = new THREE.WebGLRenderer({ antialias: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  renderer.setSize(window.innerWidth, window.innerHeight);
  renderer.setClearColor(0x000000);
  stage.appendChild(renderer.domElement);

  const lightmaps = new Map();
  const loader = new GLTFLoader().register((parser) => new MozLightmap(parser, lightmaps));
  const gltf = await new Promise((resolve, reject) =>
    loader.load("/scene.glb", resolve, undefined, reject));
  const lightmapped = lightmaps.size > 0;
  const scene = new THREE.Scene();
  scene.add(gltf.scene);
  gltf.scene.updateMatrixWorld(true);

  // Materials: baked radiance where there is one, grey where the bake has
  // nothing (the non-diffuse surfaces it leaves to a renderer). The bake
  // writes each lit side of a surface as its own triangles, wound to face
  // that side: front faces only, so that the two sides of a wall do not
  // fight, and a closed room seen from outside shows its inside.
  const baked = new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.FrontSide });
  const unbaked = new THREE.MeshBasicMaterial({ color: 0x606060, side: THREE.DoubleSide });
  const wires = [];
  let triangles = 0;
  let hasUnbaked = false;
  // lightmapped: each mesh's own material, its lightmap and error map
  const lit = [];
  // the asset's own lamps (KHR_lights_punctual) are kept in the .glb, but
  // their light is already in the lightmap: switched off here, or it would
  // be counted twice
  let lampsOff = 0;
  gltf.scene.traverse((o) => {
    if (o.isLight && lightmapped) {
      o.visible = false;
      lampsOff += 1;
      return;
    }
    if (!o.isMesh) return;
    const g = o.geometry;
    const radiance = g.getAttribute("_radiance");
    if (lightmapped) {
      const assoc = gltf.parser.associations.get(o.material);
      const lm = assoc && lightmaps.get(assoc.materials);
      lit.push({
        mesh: o, own: o.material, lm,
        emissive: o.material.emissiveIntensity === undefined ? 0 : o.material.emissiveIntensity,
        error: lm && lm.err ? errorMaterial(lm.lightMap, lm.err) : null,
      });
      if (!lm) hasUnbaked = true;
    } else if (radiance) {
      g.setAttribute("color", radiance);
      o.material = baked;
    } else {
      o.material = unbaked;
      hasUnbaked = true;
    }
    triangles += g.index ? g.index.count / 3 : g.getAttribute("position").count / 3;
    const wire = new THREE.LineSegments(new THREE.WireframeGeometry(g),
      new THREE.LineBasicMaterial({ color: 0x00ffff, transparent: true, opacity: 0.5 }));
    wire.visible = false;
    o.add(wire);
    wires.push(wire);
  });

  const box = new THREE.Box3().setFromObject(gltf.scene);
  const centre = box.getCenter(new THREE.Vector3());
  const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-6);

  const camera = new THREE.PerspectiveCamera(45, window.innerWidth / window.innerHeight,
    radius * 1e-3, radius * 100);
  const sceneCamera = gltf.cameras.find((c) => c.isPerspectiveCamera);
  // OrbitControls orbits about the camera's up at its creation: the scene
  // camera's, when there is one
  if (sceneCamera) {
    sceneCamera.updateMatrixWorld(true);
    const q = new THREE.Quaternion();
    sceneCamera.matrixWorld.decompose(new THREE.Vector3(), q, new THREE.Vector3());
    camera.up.set(0, 1, 0).applyQuaternion(q);
  }
  const controls = new OrbitControls(camera, renderer.domElement);

  // The first view: the scene's camera when the bake recorded it, else the
  // whole mesh framed from its front
  function home() {
    if (sceneCamera) {
      sceneCamera.updateMatrixWorld(true);
      const m = sceneCamera.matrixWorld;
      m.decompose(camera.position, camera.quaternion, new THREE.Vector3());
      camera.fov = sceneCamera.fov;
      camera.near = sceneCamera.near;
      const forward = new THREE.Vector3(0, 0, -1).applyQuaternion(camera.quaternion);
      // orbit about the point on the view axis nearest the mesh's centre
      const d = Math.max(centre.clone().sub(camera.position).dot(forward), radius * 1e-2);
      controls.target.copy(camera.position).addScaledVector(forward, d);
      camera.far = Math.max(camera.position.distanceTo(centre) + radius, 1e-3) * 2;
    } else {
      camera.fov = 45;
      camera.position.copy(centre).add(new THREE.Vector3(0, 0, radius * 2.5));
      camera.near = radius * 1e-3;
      camera.far = radius * 100;
      controls.target.copy(centre);
      camera.lookAt(centre);
    }
    camera.updateProjectionMatrix();
    controls.update();
    draw();
  }

  function draw() {
    renderer.render(scene, camera);
  }

  function expose() {
    const v = Number($("exposure").value);
    $("exposure-value").textContent = v.toFixed(1);
    const k = Math.pow(2, v);
    baked.color.setScalar(k);
    for (const l of lit) {
      if (l.lm) l.own.lightMapIntensity = l.lm.intensity * k;
      if (l.emissive) l.own.emissiveIntensity = l.emissive * k;
    }
    draw();
  }

  function showError(on) {
    for (const l of lit) l.mesh.material = on && l.error ? l.error : l.own;
    draw();
  }
  const hasError = lit.some((l) => l.error);
  $("error-map-row").hidden = !hasError;
  $("error-map").onchange = () => showError($("error-map").checked);

  $("exposure").oninput = expose;
  $("wireframe").onchange = () => {
    for (const w of wires) w.visible = $("wireframe").checked;
    draw();
  };
  $("reset").onclick = home;
  $("reset").hidden = !sceneCamera;
  $("camera-note").textContent =
    `${Math.round(triangles)} triangles; ` +
    (sceneCamera ? "first view: the scene's camera" : "the bake holds no camera") +
    (lightmapped ? "; lightmap on uv 1" : "") +
    (lampsOff ? `; ${lampsOff} lamp(s) off (their light is in the lightmap)` : "") +
    (hasUnbaked ? (lightmapped ? "; some materials have no lightmap (specular)"
      : "; grey: not baked (specular)") : "");
  controls.addEventListener("change", draw);
  window.addEventListener("resize", () => {
    camera.aspect = window.innerWidth / window.innerHeight;
    camera.updateProjectionMatrix();
    renderer.setSize(window.innerWidth, window.innerHeight);
    draw();
  });

  // hooks for the browser test and for scripts
  window.kalos.triangles = triangles;
  window.kalos.sceneCamera = !!sceneCamera;
  window.kalos.setExposure = (v) => { $("exposure").value = v; expose(); };
  window.kalos.lightmapped = lightmapped;
  window.kalos.lampsOff = lampsOff;
  window.kalos.lightmaps = lightmaps.size;
  window.kalos.setErrorMap = (on) => { $("error-map").checked = on; showError(on); };
  home();
  expose();
  requestAnimationFrame(() => { window.kalos.ready = true; });
}
