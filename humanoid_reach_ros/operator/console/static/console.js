// The operator console's page: the robot's 3D perception (voxel map, unobserved frontier,
// target, the robot from its collision capsules), the head camera, the controls.
// Frames and messages: humanoid_reach_ros/operator/console/views.py (binary) and control.py (JSON).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const $ = (id) => document.getElementById(id);
const canvas = $("scene");
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x262b31);
const camera = new THREE.PerspectiveCamera(45, 1, 0.02, 50);
camera.up.set(0, 0, 1);                          // ROS: z up
camera.position.set(-0.7, -2.1, 1.7);
const controls = new OrbitControls(camera, canvas);
controls.target.set(0.45, 0.0, 0.85);
controls.update();
scene.add(new THREE.HemisphereLight(0xffffff, 0x404850, 2.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(-1, -2, 4);
scene.add(sun);
const grid = new THREE.GridHelper(4, 20, 0x556070, 0x3a424c);
grid.rotation.x = Math.PI / 2;                   // in the floor plane z = 0
scene.add(grid);
scene.add(new THREE.AxesHelper(0.3));

let dirty = true;
const hr = {                                      // what the page shows, for tests and the curious
  page: null, holder: null, busy: null, preview: false, picked: null,
  counts: { occupied: 0, unobserved: 0, robotFrames: 0, ghostFrames: 0, images: 0, markerImages: 0, renders: 0 },
  results: [], errors: [], status: null,
  project(x, y, z) {                              // a world point -> page pixel coordinates
    const v = new THREE.Vector3(x, y, z).project(camera);
    const r = canvas.getBoundingClientRect();
    return { x: r.left + (v.x + 1) / 2 * r.width, y: r.top + (1 - v.y) / 2 * r.height, visible: Math.abs(v.z) < 1 };
  },
};
window.hr = hr;

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
  dirty = true;
}
window.addEventListener("resize", resize);
controls.addEventListener("change", () => { dirty = true; });

// ---------------------------------------------------------------- voxel layers
const layers = {
  occupied: { keys: new Map(), res: 0.02, mesh: null },
  unobserved: { keys: new Map(), res: 0.02, mesh: null },
};
const code = (x, y, z) => ((x + 32768) * 65536 + (y + 32768)) * 65536 + (z + 32768);

async function inflate(bytes) {
  const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Int16Array(await new Response(stream).arrayBuffer());
}

async function onVoxels(h, payload) {
  const layer = layers[h.layer];
  if (!layer) return;
  const keys = await inflate(payload);
  if (h.full) layer.keys.clear();
  layer.res = h.res;
  for (let i = 0; i < h.added; i++) {
    const x = keys[3 * i], y = keys[3 * i + 1], z = keys[3 * i + 2];
    layer.keys.set(code(x, y, z), [x, y, z]);
  }
  for (let i = h.added; i < h.added + h.removed; i++) layer.keys.delete(code(keys[3 * i], keys[3 * i + 1], keys[3 * i + 2]));
  rebuildLayer(h.layer);
}

const voxelColor = new THREE.Color();
function rebuildLayer(name) {
  const layer = layers[name];
  if (layer.mesh) { scene.remove(layer.mesh); layer.mesh.geometry.dispose(); layer.mesh.material.dispose(); }
  const n = layer.keys.size, res = layer.res;
  hr.counts[name] = n;
  if (name === "occupied") {
    const mesh = new THREE.InstancedMesh(new THREE.BoxGeometry(res * 0.92, res * 0.92, res * 0.92),
      new THREE.MeshLambertMaterial({ color: 0xffffff }), Math.max(n, 1));
    const m = new THREE.Matrix4();
    let i = 0;
    for (const [x, y, z] of layer.keys.values()) {
      m.makeTranslation((x + 0.5) * res, (y + 0.5) * res, (z + 0.5) * res);
      mesh.setMatrixAt(i, m);
      voxelColor.setHSL(0.58 - 0.3 * Math.min(1, Math.max(0, (z + 0.5) * res / 2)), 0.25, 0.62);
      mesh.setColorAt(i++, voxelColor);
    }
    mesh.count = n;
    layer.mesh = mesh;
  } else {
    const pos = new Float32Array(3 * n);
    let i = 0;
    for (const [x, y, z] of layer.keys.values()) {
      pos[i++] = (x + 0.5) * res; pos[i++] = (y + 0.5) * res; pos[i++] = (z + 0.5) * res;
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.BufferAttribute(pos, 3));
    layer.mesh = new THREE.Points(g, new THREE.PointsMaterial({ color: 0xe8913a, size: res * 0.6,
      transparent: true, opacity: 0.22, depthWrite: false }));
  }
  scene.add(layer.mesh);
  dirty = true;
}

// ---------------------------------------------------------------- the robot and its ghost
let radii = [];
function capsuleSet(material) { return { meshes: [], group: new THREE.Group(), material }; }
const body = capsuleSet(new THREE.MeshStandardMaterial({ color: 0xc9ced6, roughness: 0.6, metalness: 0.1 }));
const ghost = capsuleSet(new THREE.MeshStandardMaterial({ color: 0x5fb4ff, transparent: true, opacity: 0.35,
  depthWrite: false }));
scene.add(body.group, ghost.group);
const yAxis = new THREE.Vector3(0, 1, 0), a = new THREE.Vector3(), b = new THREE.Vector3(), d = new THREE.Vector3();

function placeCapsules(set, ends, offset, count) {
  if (!set.meshes.length) {                        // built from the first posture: a capsule's length is fixed
    for (let s = 0; s < count; s++) {
      const i = offset + 3 * s, j = offset + 3 * (count + s);
      const len = Math.hypot(ends[j] - ends[i], ends[j + 1] - ends[i + 1], ends[j + 2] - ends[i + 2]);
      const g = len < 1e-6 ? new THREE.SphereGeometry(radii[s], 16, 12) : new THREE.CapsuleGeometry(radii[s], len, 6, 14);
      const mesh = new THREE.Mesh(g, set.material);
      set.meshes.push(mesh);
      set.group.add(mesh);
    }
  }
  for (let s = 0; s < count; s++) {
    const i = offset + 3 * s, j = offset + 3 * (count + s);
    a.set(ends[i], ends[i + 1], ends[i + 2]);
    b.set(ends[j], ends[j + 1], ends[j + 2]);
    const mesh = set.meshes[s];
    mesh.position.copy(a).add(b).multiplyScalar(0.5);
    d.copy(b).sub(a);
    if (d.lengthSq() > 1e-12) mesh.quaternion.setFromUnitVectors(yAxis, d.normalize());
  }
  dirty = true;
}

let ghostFrames = null, ghostStart = 0;
function onGhost(h, payload) {
  ghostFrames = { data: new Float32Array(payload), n: h.frames, shapes: h.shapes, times: h.times };
  hr.counts.ghostFrames = h.frames;
  ghostStart = performance.now();
  ghost.group.visible = true;
}
function clearGhost() { ghostFrames = null; ghost.group.visible = false; hr.counts.ghostFrames = 0; dirty = true; }
function animateGhost(now) {
  if (!ghostFrames) return;
  const { data, n, shapes, times } = ghostFrames;
  const span = times[n - 1] - times[0] + 1.0;       // the motion, then a second at its end
  const t = times[0] + ((now - ghostStart) / 1000) % span;
  let k = 0;
  while (k < n - 1 && times[k + 1] <= t) k++;
  placeCapsules(ghost, data, k * shapes * 6, shapes);
}

// ---------------------------------------------------------------- markers in the scene
function dot(color, r) {   // drawn over everything: a target inside the voxels stays visible
  const m = new THREE.Mesh(new THREE.SphereGeometry(r, 16, 12), new THREE.MeshBasicMaterial({ color, depthTest: false }));
  m.renderOrder = 10;
  m.visible = false;
  scene.add(m);
  return m;
}
const pickedDot = dot(0xff3b3b, 0.025), markerDot = dot(0x3bd16f, 0.02);
const lookDots = [];
function showLooked(points) {
  for (const m of lookDots) scene.remove(m);
  lookDots.length = 0;
  for (const p of points) { const m = dot(0xf5e050, 0.03); m.position.set(...p); m.visible = true; lookDots.push(m); }
  dirty = true;
}

// ---------------------------------------------------------------- picking
const ray = new THREE.Raycaster(), mouse = new THREE.Vector2();
let down = null;
canvas.addEventListener("pointerdown", (e) => { down = [e.clientX, e.clientY]; });
canvas.addEventListener("pointerup", (e) => {
  if (!down || Math.hypot(e.clientX - down[0], e.clientY - down[1]) > 4) return;   // a drag turns the view
  const r = canvas.getBoundingClientRect();
  mouse.set((e.clientX - r.left) / r.width * 2 - 1, -(e.clientY - r.top) / r.height * 2 + 1);
  ray.setFromCamera(mouse, camera);
  const occ = layers.occupied.mesh;
  const hit = occ && occ.count ? ray.intersectObject(occ, false)[0] : null;
  if (!hit) { say("no map voxel under the cursor: click on a grey voxel of the map", "bad"); return; }
  const p = hit.point;
  hr.picked = [p.x, p.y, p.z].map((v) => Math.round(v * 1000) / 1000);
  pickedDot.position.set(...hr.picked);
  pickedDot.visible = true;
  $("picked").textContent = `(${hr.picked.map((v) => v.toFixed(3)).join(", ")}) m`;
  dirty = true;
  updateButtons();
});

// ---------------------------------------------------------------- camera image
const imageCtx = $("image").getContext("2d");
async function onImage(h, payload) {
  const bmp = await createImageBitmap(new Blob([payload], { type: "image/jpeg" }));
  const c = $("image");
  if (c.width !== h.w || c.height !== h.h) { c.width = h.w; c.height = h.h; }
  imageCtx.drawImage(bmp, 0, 0);
  imageCtx.lineWidth = 3;
  imageCtx.strokeStyle = "#3bd16f";
  for (const q of h.markers) {
    imageCtx.beginPath();
    q.forEach(([u, v], i) => (i ? imageCtx.lineTo(u, v) : imageCtx.moveTo(u, v)));
    imageCtx.closePath();
    imageCtx.stroke();
  }
  hr.counts.images++;
  if (h.markers.length) hr.counts.markerImages++;
  $("imageinfo").textContent = `head camera ${h.w} x ${h.h}, ${h.markers.length ? "marker outlined" : "no marker in view"}`;
}

// ---------------------------------------------------------------- the connection
let ws = null;
function connect() {
  ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = "arraybuffer";
  ws.onmessage = (ev) => (typeof ev.data === "string" ? onText(JSON.parse(ev.data)) : onBinary(ev.data));
  ws.onclose = () => { $("holder").textContent = "disconnected: reconnecting ..."; hr.page = null; setTimeout(connect, 2000); };
}
function send(req) {
  if (!ws || ws.readyState !== WebSocket.OPEN) { say("not connected to the console", "bad"); return; }
  ws.send(typeof req === "string" ? req : JSON.stringify(req));
}
hr.send = send;                                   // a request as the buttons send it (tests send bad ones)

function onBinary(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const h = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const payload = buf.slice(4 + n);
  if (h.t === "voxels") onVoxels(h, payload);
  else if (h.t === "robot") { placeCapsules(body, new Float32Array(payload), 0, h.shapes); hr.counts.robotFrames++; }
  else if (h.t === "ghost") onGhost(h, payload);
  else if (h.t === "image") onImage(h, payload);
}

function say(text, cls) { const r = $("result"); r.textContent = text; r.className = cls || ""; }
function log(text, cls) {
  const div = document.createElement("div");
  div.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (cls) div.className = cls;
  const l = $("log");
  l.appendChild(div);
  while (l.childNodes.length > 300) l.removeChild(l.firstChild);
  l.scrollTop = l.scrollHeight;
}
function progress(fraction, text) {
  $("bar").style.width = `${Math.round(100 * Math.min(1, Math.max(0, fraction || 0)))}%`;
  $("progresstext").textContent = text || "";
}

function onText(m) {
  if (m.t === "hello") { hr.page = m.page; radii = m.robot.radii; log(`connected as page ${m.page}; robot ${m.robot.name}, ${radii.length} shapes`); }
  else if (m.t === "status") onStatus(m);
  else if (m.t === "log") log(m.text, m.level === "error" ? "error" : "");
  else if (m.t === "progress") progress(m.fraction, `${m.op}: ${m.text}`);
  else if (m.t === "looked") { showLooked(m.points); log(`automatic look at ${JSON.stringify(m.points)}`, "mine"); }
  else if (m.t === "ghost_clear") clearGhost();
  else if (m.t === "error") { hr.errors.push(m); say(m.text, "bad"); log(m.text, "error"); }
  else if (m.t === "result") {
    hr.results.push(m);
    say(m.text, m.ok ? "ok" : "bad");
    log(m.text.split("\n")[0], m.ok ? "" : "error");
    progress(m.ok ? 1 : 0, `${m.op}: ${m.ok ? "done" : "failed"}`);
    if (m.plan) $("stats").textContent = planStats(m.plan);
  }
}

function planStats(p) {
  const s = p.statistics, t = p.trajectory;
  return `${p.arm} arm, ${t.points} points, ${t.duration_s.toFixed(2)} s of motion\n` +
    `goals ${s.goals_found}/${s.goals_requested} in ${(s.goal_sampling_time_s * 1e3).toFixed(0)} ms, path ` +
    `${(s.path_planning_time_s * 1e3).toFixed(0)} ms (${s.path_waypoints} waypoints), total ${(s.total_time_s * 1e3).toFixed(0)} ms\n` +
    `${s.collision_checks} collision checks, map ${s.map_voxels} voxels`;
}

function onStatus(m) {
  hr.status = m; hr.holder = m.holder; hr.busy = m.busy; hr.preview = m.preview;
  const mine = m.holder !== null && m.holder === hr.page;
  $("holder").textContent = mine ? "you hold the controls" : m.holder === null ? "the controls are free" :
    `page ${m.holder} holds the controls: view only`;
  if (m.marker_target) { markerDot.position.set(...m.marker_target); markerDot.visible = true; }
  const err = m.last_error ? `${m.last_error.name}${m.last_error.code != null ? ` (${m.last_error.code})` : ""}: ${m.last_error.message}` : "none";
  $("status").textContent = `executor ${m.executor || "?"}${m.busy ? `, console busy: ${m.busy}` : ""} | overruns ` +
    `${m.overruns_total ?? "?"} | voxels ${m.voxels.occupied}, frontier ${m.voxels.unobserved} | last error: ${err}`;
  updateButtons();
}

function updateButtons() {
  const mine = hr.page !== null && hr.holder === hr.page, idle = mine && !hr.busy;
  $("take").disabled = hr.holder !== null;
  $("release").disabled = !mine;
  $("plan").disabled = !(idle && hr.picked);
  $("look").disabled = !(idle && hr.picked);
  $("execute").disabled = !(idle && hr.preview);
  $("scan").disabled = $("home").disabled = !idle;
  $("cancel").disabled = !(mine && hr.busy);
}

$("take").onclick = () => send({ op: "take" });
$("release").onclick = () => send({ op: "release" });
$("plan").onclick = () => { progress(0, "plan: planning ..."); send({ op: "plan", target: hr.picked, arm: $("arm").value }); };
$("execute").onclick = () => { progress(0, "execute: starting ..."); send({ op: "execute" }); };
$("cancel").onclick = () => send({ op: "cancel" });
$("scan").onclick = () => { progress(0, "scan: starting ..."); send({ op: "scan" }); };
$("look").onclick = () => { progress(0, "look: starting ..."); send({ op: "look", point: hr.picked }); };
$("home").onclick = () => { progress(0, "home: planning ..."); send({ op: "home" }); };

function frame(now) {
  animateGhost(now);
  if (dirty) { renderer.render(scene, camera); dirty = false; hr.counts.renders++; }
  requestAnimationFrame(frame);
}
resize();
updateButtons();
connect();
requestAnimationFrame(frame);
