// The preview page: shows each new render as the server announces it
// (server-sent events), and sends camera moves and controls back.
"use strict";

const token = new URLSearchParams(location.search).get("token");
const view = document.getElementById("view");
const errorBox = document.getElementById("error");
const message = document.getElementById("message");
let shown = -1;
let lookat = "";

function api(path) {
  return `${path}?token=${encodeURIComponent(token)}`;
}

async function post(path, body) {
  const answer = await fetch(api(path), {method: "POST", body: JSON.stringify(body || {}),
                                         headers: {"Content-Type": "application/json"}});
  const value = await answer.json();
  if (value.error) message.textContent = value.error;
  return value;
}

function number(value, digits) {
  return value === null || value === undefined ? "-" : value.toPrecision(digits);
}

function showStatus(status) {
  if (status.generation !== shown && status.generation > 0) {
    shown = status.generation;
    view.src = `${api("/image.png")}&generation=${shown}`;
  }
  errorBox.hidden = status.state !== "error";
  errorBox.textContent = status.error || "";
  document.getElementById("state").textContent = status.state;
  const rate = status.rays_per_second ? `, ${number(status.rays_per_second / 1e6, 3)} M rays/s` : "";
  const photons = status.passes === null || status.passes === undefined ? "" :
    `, photon passes ${status.passes} (the scene's ${status.photon_passes})`;
  document.getElementById("stats").textContent = status.seconds === null ? "" :
    `${status.width} x ${status.height}, aa ${status.aa || "-"}: ` +
    `${number(status.seconds, 3)} s${rate}${photons}`;
  lookat = status.lookat || "";
  const settings = status.settings || {};
  for (const name of ["aa", "max_depth", "indirect_samples"]) {
    const control = document.getElementById(name);
    control.disabled = !(name in settings);
    if (name in settings && document.activeElement !== control) control.value = settings[name];
  }
}

new EventSource(api("/events")).onmessage = event => showStatus(JSON.parse(event.data));

// Camera moves: while one is on its way, the next ones add up.
const pending = {orbit: [0, 0], pan: [0, 0], dolly: [0, 0]};
let sending = false;

async function sendMoves() {
  if (sending) return;
  sending = true;
  for (const move of Object.keys(pending)) {
    const [x, y] = pending[move];
    if (x === 0 && y === 0) continue;
    pending[move] = [0, 0];
    await post("/camera", {move, x, y});
  }
  sending = false;
  if (Object.values(pending).some(([x, y]) => x !== 0 || y !== 0)) sendMoves();
}

function queue(move, x, y) {
  pending[move][0] += x;
  pending[move][1] += y;
  sendMoves();
}

let drag = null;
view.addEventListener("pointerdown", event => {
  drag = {x: event.clientX, y: event.clientY};
  view.setPointerCapture(event.pointerId);
});
view.addEventListener("pointermove", event => {
  if (!drag) return;
  const dx = (event.clientX - drag.x) / view.clientWidth;
  const dy = (event.clientY - drag.y) / view.clientHeight;
  drag = {x: event.clientX, y: event.clientY};
  if (event.shiftKey) queue("pan", dx, dy);
  else queue("orbit", -dx * Math.PI, -dy * Math.PI);
});
view.addEventListener("pointerup", () => { drag = null; });
view.addEventListener("wheel", event => {
  event.preventDefault();
  queue("dolly", event.deltaY / 1000, 0);
}, {passive: false});

document.getElementById("reset").onclick = () => post("/camera", {move: "reset"});
document.getElementById("save").onclick = async () => {
  const answer = await post("/save");
  if (answer.saved) message.textContent = `saved ${answer.saved}`;
};
document.getElementById("copy").onclick = async () => {
  try {
    await navigator.clipboard.writeText(lookat);
    message.textContent = "copied: " + lookat;
  } catch (error) {
    message.textContent = lookat;  // to copy by hand
  }
};

const exposure = document.getElementById("exposure");
exposure.addEventListener("input", () => {
  document.getElementById("exposure-value").textContent = exposure.value;
  post("/settings", {exposure: Number(exposure.value)});
});
document.getElementById("aa").addEventListener("change", event =>
  post("/settings", {aa: event.target.value}));
for (const name of ["max_depth", "indirect_samples"]) {
  document.getElementById(name).addEventListener("change", event =>
    post("/settings", {[name]: Number(event.target.value)}));
}
