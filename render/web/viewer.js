// scan2render's web viewer (written by `s2r export web`): the model's
// microfacet billboards with depth clipping in WebGL2, drawn as `s2r render`
// draws them (render/model_renderer.cpp, render/facet_selection.cpp): each
// facet a camera-facing square of sqrt(3) w, the K best input cameras by
// angle blended with weights that fall to 0 as a camera leaves the best K,
// blends under a 10 % share left out, depth clipping against each camera's
// distances (widened where the texel's misplacement stays under half a
// pixel), free-space carving by the nearest input camera, texel refinement
// along the view ray. No network, no build step: open index.html from any
// static server. ?view=VIEW.json draws an s2r.view pose at its own size.
'use strict';

const $ = (id) => document.getElementById(id);
const status = (s) => { $('status').textContent = s; };

function fail(message) {
  console.error(message);
  $('error').style.display = 'block';
  $('error').textContent = message;
  $('progress').style.display = 'none';
  window.s2r = Object.assign(window.s2r || {}, { error: message });
}

async function fetchBytes(url, onBytes) {
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  if (!r.body || !r.body.getReader) {
    const b = await r.arrayBuffer();
    onBytes(b.byteLength);
    return b;
  }
  const reader = r.body.getReader();
  const parts = [];
  let n = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    parts.push(value);
    n += value.length;
    onBytes(value.length);
  }
  const out = new Uint8Array(n);
  let o = 0;
  for (const p of parts) { out.set(p, o); o += p.length; }
  return out.buffer;
}

// ---- small linear algebra (column-major 4x4 as in GLSL; vectors as arrays) ----
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => Math.sqrt(dot(a, a));
const normalize = (a) => { const n = norm(a); return n > 0 ? scale(a, 1 / n) : a; };
const angleBetween = (a, b) => Math.atan2(norm(cross(a, b)), dot(a, b));

// A view: intrinsics {width, height, fx, fy, cx, cy, dist[5]} and a pose as
// rotation columns (x right, y down, z forward) and the eye.
function viewFromPose(K, m) {  // m: 16 numbers, row-major world_from_camera
  return {
    K,
    right: [m[0], m[4], m[8]], down: [m[1], m[5], m[9]], fwd: [m[2], m[6], m[10]],
    eye: [m[3], m[7], m[11]],
  };
}
// camera_from_world as a column-major mat4 for GLSL.
function cfwMatrix(v) {
  const R = [v.right, v.down, v.fwd];
  const t = R.map((r) => -dot(r, v.eye));
  return new Float32Array([
    R[0][0], R[1][0], R[2][0], 0,
    R[0][1], R[1][1], R[2][1], 0,
    R[0][2], R[1][2], R[2][2], 0,
    t[0], t[1], t[2], 1]);
}
const toCamera = (v, p) => { const d = sub(p, v.eye); return [dot(v.right, d), dot(v.down, d), dot(v.fwd, d)]; };

// ---- shaders: GLSL ES 3.00 ports of render/model_renderer.cpp ----
const COMMON = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2D;
precision highp sampler2DArray;
vec2 distort(vec2 x, vec4 d, float k3) {
  float r2 = dot(x, x);
  float radial = 1.0 + r2 * (d.x + r2 * (d.y + r2 * k3));
  return x * radial + vec2(2.0 * d.z * x.x * x.y + d.w * (r2 + 2.0 * x.x * x.x),
                           d.z * (r2 + 2.0 * x.y * x.y) + 2.0 * d.w * x.x * x.y);
}
uniform sampler2D u_cams;  // 8 texels a camera: cfw columns, k, d, extra (k3 width height layer), centre (w: max r^2)
struct Cam { mat4 cfw; vec4 k; vec4 d; vec4 extra; vec4 centre; };
Cam cam(int i) {
  Cam c;
  c.cfw = mat4(texelFetch(u_cams, ivec2(0, i), 0), texelFetch(u_cams, ivec2(1, i), 0),
               texelFetch(u_cams, ivec2(2, i), 0), texelFetch(u_cams, ivec2(3, i), 0));
  c.k = texelFetch(u_cams, ivec2(4, i), 0);
  c.d = texelFetch(u_cams, ivec2(5, i), 0);
  c.extra = texelFetch(u_cams, ivec2(6, i), 0);
  c.centre = texelFetch(u_cams, ivec2(7, i), 0);
  return c;
}
uniform mat4 u_view_cfw;
uniform vec4 u_view_k;
uniform vec4 u_view_d;
uniform float u_view_k3;
uniform vec2 u_view_size;
uniform vec2 u_near_far;
uniform int u_view_distort;
vec4 to_clip(vec3 world) {
  vec3 p = (u_view_cfw * vec4(world, 1.0)).xyz;
  float n = u_near_far.x, f = u_near_far.y;
  vec2 q = p.xy;
  if (u_view_distort != 0 && p.z > n) q = distort(p.xy / p.z, u_view_d, u_view_k3) * p.z;
  float cx = (2.0 * u_view_k.x * q.x + (2.0 * u_view_k.z + 1.0) * p.z) / u_view_size.x - p.z;
  float cy = p.z - (2.0 * u_view_k.y * q.y + (2.0 * u_view_k.w + 1.0) * p.z) / u_view_size.y;
  return vec4(cx, cy, (f + n) / (f - n) * p.z - 2.0 * f * n / (f - n), p.z);
}
`;

const VERTEX = COMMON + `
layout(location = 0) in vec4 a_facet;    // centre xyz, size
layout(location = 1) in float a_rel;
layout(location = 2) in ivec4 a_cams;
layout(location = 3) in vec4 a_weights;
uniform vec3 u_eye;
uniform vec3 u_up;
uniform float u_scale;
out vec3 v_world;
flat out ivec4 v_cams;
flat out vec4 v_weights;
flat out float v_size;
flat out float v_rel;
void main() {
  vec3 c = a_facet.xyz;
  vec3 v = u_eye - c;
  float len = length(v);
  v = len > 0.0 ? v / len : vec3(0.0, 0.0, 1.0);
  vec3 r = cross(u_up, v);
  if (dot(r, r) < 1e-12) r = cross(abs(v.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0), v);
  r = normalize(r);
  vec3 up = cross(v, r);
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;
  v_world = c + (corner.x * r + corner.y * up) * (0.5 * u_scale * a_facet.w);
  gl_Position = to_clip(v_world);
  v_cams = a_cams;
  v_weights = a_weights;
  v_size = a_facet.w;
  v_rel = a_rel;
}
`;

const FRAGMENT = COMMON + `
uniform sampler2DArray u_color;
uniform sampler2DArray u_dist;
uniform vec2 u_tex_size;
in vec3 v_world;
flat in ivec4 v_cams;
flat in vec4 v_weights;
flat in float v_size;
flat in float v_rel;
uniform int u_clip;
uniform float u_clip_scale;
uniform int u_probe;
uniform int u_refine;
uniform int u_clip_fuzzy;
uniform vec3 u_eye;
uniform vec3 u_view_forward;
uniform float u_view_focal;
uniform float u_px_error;
out vec4 frag;
int camera_at(int ci, vec3 P, float tol, out vec3 col, out float D, out float d) {
  col = vec3(0.0);
  D = 0.0;
  d = 0.0;
  Cam c = cam(ci);
  if (c.extra.w < 0.0) return 0;
  vec3 p = (c.cfw * vec4(P, 1.0)).xyz;
  if (p.z <= 1e-6) return 0;
  vec2 xn = p.xy / p.z;
  if (dot(xn, xn) > c.centre.w) return 0;
  vec2 px = c.k.xy * distort(xn, c.d, c.extra.x) + c.k.zw;
  if (px.x < -0.5 || px.y < -0.5 || px.x >= c.extra.y - 0.5 || px.y >= c.extra.z - 0.5) return 0;
  col = texture(u_color, vec3((px + 0.5) / u_tex_size, c.extra.w)).rgb;
  D = texelFetch(u_dist, ivec3(ivec2(floor(px + 0.5)), int(c.extra.w)), 0).r;
  d = length(P - c.centre.xyz);
  if (!(D > 0.0) || D > d + tol) return 2;
  return D < d - tol ? 3 : 1;
}
int texel_state(int ci, vec3 P, float tol, out vec3 col) {
  float D, d;
  return camera_at(ci, P, tol, col, D, d);
}
vec3 refined(int ci, vec3 P0, float tol, vec3 col0) {
  vec3 view_dir = normalize(P0 - u_eye);
  vec3 P = P0;
  vec3 col = col0;
  vec3 centre = cam(ci).centre.xyz;
  for (int it = 0; it < u_refine; ++it) {
    vec3 c;
    float D, d;
    if (camera_at(ci, P, tol, c, D, d) != 1) break;
    col = c;
    vec3 next = P + (D - d) / max(dot(normalize(P - centre), view_dir), 0.5) * view_dir;
    if (length(next - P0) > tol) break;
    P = next;
  }
  vec3 c;
  if (P != P0 && texel_state(ci, P, tol, c) == 1) col = c;
  return col;
}
float camera_tol(int ci, float tol) {
  vec3 view_dir = normalize(v_world - u_eye);
  vec3 cam_dir = normalize(v_world - cam(ci).centre.xyz);
  float s = length(cross(view_dir, cam_dir));
  float pixel_m = u_px_error * dot(v_world - u_eye, u_view_forward) / u_view_focal;
  return max(tol, pixel_m / max(s, 1e-6));
}
void main() {
  vec3 acc = vec3(0.0);
  float wsum = 0.0;
  float tol = u_clip_scale * v_size;
  vec3 col;
  bool clip = u_clip != 0 && (u_clip_fuzzy != 0 || v_rel > 0.0);
  if (clip && u_probe >= 0 && texel_state(u_probe, v_world, camera_tol(u_probe, tol), col) == 2) discard;
  for (int j = 0; j < 4; ++j) {
    int ci = v_cams[j];
    if (ci < 0) break;
    int state = texel_state(ci, v_world, camera_tol(ci, tol), col);
    if (state == 0) continue;
    if (clip) {
      if (state == 2) discard;
      if (state == 3) continue;
      if (u_refine > 0) col = refined(ci, v_world, camera_tol(ci, tol), col);
    }
    acc += v_weights[j] * col;
    wsum += v_weights[j];
  }
  if (!(wsum > 0.0)) discard;
  frag = vec4(acc / wsum, 1.0);
}
`;

function compile(gl, type, source) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
  return s;
}

// ---- facet selection: render/facet_selection.cpp ----
const MAX_BLEND = 4;
function blendWeights(a, count, k, w) {
  if (count <= 0 || k <= 0) return 0;
  k = Math.min(k, MAX_BLEND);
  if (a[0] < 1e-6) { w[0] = 1; return 1; }
  const used = Math.min(k, count);
  const threshold = count > k ? a[k] : Math.PI;
  let sum = 0;
  const ww = [0, 0, 0, 0];
  for (let i = 0; i < used; ++i) { ww[i] = Math.max(0, 1 - a[i] / threshold) / a[i]; sum += ww[i]; }
  if (!(sum > 0)) { w[0] = 1; return 1; }
  for (let i = 0; i < used; ++i) w[i] = Math.fround(ww[i] / sum);
  return used;
}
function pruneWeights(w, used, minWeight) {
  if (used <= 1 || !(minWeight > 0)) return used;
  let kept = 1;
  let sum = w[0];
  for (let i = 1; i < used; ++i) if (w[i] >= minWeight) { w[kept++] = w[i]; sum += w[i]; }
  for (let i = 0; i < kept; ++i) w[i] = Math.fround(w[i] / sum);
  for (let i = kept; i < used; ++i) w[i] = 0;
  return kept;
}
function sphereOutsideView(v, c, radius, near) {
  const p = toCamera(v, c);
  if (p[2] + radius <= near) return true;
  if (p[2] <= radius) return false;
  const K = v.K;
  const mx = 0.1 * K.width, my = 0.1 * K.height;
  const z = p[2] - radius;
  const u = K.fx * p[0] / p[2] + K.cx, vv = K.fy * p[1] / p[2] + K.cy;
  const ru = K.fx * radius / z + mx, rv = K.fy * radius / z + my;
  return u + ru < -0.5 || vv + rv < -0.5 || u - ru > K.width - 0.5 || vv - rv > K.height - 0.5;
}

class Viewer {
  constructor(header, payloads) {
    this.h = header;
    const f = new DataView(payloads.facets);
    const n = header.facets;
    this.n = n;
    this.centre = new Float64Array(3 * n);
    this.size = new Float32Array(n);
    this.normal = new Float64Array(3 * n);
    this.rel = new Float32Array(n);
    this.first = new Uint32Array(n);
    this.count = new Uint32Array(n);
    for (let i = 0; i < n; ++i) {
      const o = 40 * i;
      for (let a = 0; a < 3; ++a) {
        this.centre[3 * i + a] = f.getFloat32(o + 4 * a, true);
        this.normal[3 * i + a] = f.getFloat32(o + 16 + 4 * a, true);
      }
      this.size[i] = f.getFloat32(o + 12, true);
      this.rel[i] = f.getFloat32(o + 28, true);
      this.first[i] = f.getUint32(o + 32, true);
      this.count[i] = f.getUint32(o + 36, true);
    }
    this.facetCameras = new Uint32Array(payloads.facet_cameras);
    this.cams = header.cameras;
    this.camCentres = this.cams.map((c) => c.centre);
    this.instances = new ArrayBuffer(n * 52);
    this.instF = new Float32Array(this.instances);
    this.instI = new Int32Array(this.instances);
    const canvas = $('view');
    const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true, alpha: false, depth: true });
    if (!gl) throw new Error('this browser has no WebGL2');
    this.gl = gl;
    const prog = gl.createProgram();
    gl.attachShader(prog, compile(gl, gl.VERTEX_SHADER, VERTEX));
    gl.attachShader(prog, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error('program: ' + gl.getProgramInfoLog(prog));
    this.prog = prog;
    this.u = {};
    const count = gl.getProgramParameter(prog, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < count; ++i) {
      const name = gl.getActiveUniform(prog, i).name;
      this.u[name] = gl.getUniformLocation(prog, name);
    }
    // Camera textures: two arrays, each layer a camera's image in its top-left corner.
    const W = header.texture_width, H = header.texture_height, L = header.layers;
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    gl.activeTexture(gl.TEXTURE0);
    this.color = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, this.color);
    gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl.RGBA8, W, H, L);
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, 0, W, H, L, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(payloads.colour));
    for (const [p, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
      [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]]) gl.texParameteri(gl.TEXTURE_2D_ARRAY, p, v);
    gl.activeTexture(gl.TEXTURE1);
    this.dist = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, this.dist);
    gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl.R32F, W, H, L);
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, 0, W, H, L, gl.RED, gl.FLOAT, new Float32Array(payloads.distance));
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D_ARRAY, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.activeTexture(gl.TEXTURE2);
    this.camTex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, this.camTex);
    const ct = new Float32Array(this.cams.length * 32);
    this.cams.forEach((c, i) => ct.set(c.gpu, 32 * i));
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, 8, Math.max(1, this.cams.length));
    if (this.cams.length) gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, 8, this.cams.length, gl.RGBA, gl.FLOAT, ct);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    // Instances: centre+size, reliability, 4 cameras, 4 weights (52 bytes).
    this.vao = gl.createVertexArray();
    gl.bindVertexArray(this.vao);
    this.vbo = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, this.vbo);
    gl.enableVertexAttribArray(0);
    gl.vertexAttribPointer(0, 4, gl.FLOAT, false, 52, 0);
    gl.vertexAttribDivisor(0, 1);
    gl.enableVertexAttribArray(1);
    gl.vertexAttribPointer(1, 1, gl.FLOAT, false, 52, 16);
    gl.vertexAttribDivisor(1, 1);
    gl.enableVertexAttribArray(2);
    gl.vertexAttribIPointer(2, 4, gl.INT, 52, 20);
    gl.vertexAttribDivisor(2, 1);
    gl.enableVertexAttribArray(3);
    gl.vertexAttribPointer(3, 4, gl.FLOAT, false, 52, 36);
    gl.vertexAttribDivisor(3, 1);
    gl.bindVertexArray(null);
    this.hasReliable = this.rel.some((r) => r > 0);
  }

  // The textured camera most like the view (render/model_renderer.cpp nearest_camera).
  nearestCamera(v) {
    const b = this.h.bounds;
    const radius = 0.5 * norm(sub(b.max, b.min));
    let best = -1, bestScore = Infinity;
    this.cams.forEach((c, i) => {
      if (c.layer < 0) return;
      const s = norm(sub(c.centre, v.eye)) + radius * (1 - dot(v.fwd, c.fwd));
      if (s < bestScore) { bestScore = s; best = i; }
    });
    return best;
  }

  depthRange(v) {
    const b = this.h.bounds;
    let far = 0;
    for (let c = 0; c < 8; ++c) {
      const p = [c & 1 ? b.max[0] : b.min[0], c & 2 ? b.max[1] : b.min[1], c & 4 ? b.max[2] : b.min[2]];
      far = Math.max(far, norm(sub(p, v.eye)));
    }
    far = Math.min(Math.max(far * 1.05, 1e-3), 100);
    const d = [0, 1, 2].map((a) => Math.max(b.min[a] - v.eye[a], 0, v.eye[a] - b.max[a]));
    const outside = norm(d);
    const near = Math.min(Math.max(0.5 * outside, Math.max(far * 1e-5, 1e-5)), Math.max(0.01, far * 1e-5));
    return [Math.fround(near), Math.fround(far)];
  }

  select(v, near) {
    const o = this.h.draw;
    const k = Math.min(Math.max(o.cameras, 1), MAX_BLEND);
    const list = [];
    const cams = [];
    const w = [0, 0, 0, 0];
    const angles = [0, 0, 0, 0, 0];
    const F = this.instF, I = this.instI;
    let drawn = 0;
    for (let i = 0; i < this.n; ++i) {
      const c = [this.centre[3 * i], this.centre[3 * i + 1], this.centre[3 * i + 2]];
      if (sphereOutsideView(v, c, 0.5 * Math.sqrt(3) * this.size[i], near)) continue;
      let toEye = sub(v.eye, c);
      const dist = norm(toEye);
      if (dist > 0) toEye = scale(toEye, 1 / dist);
      const nrm = [this.normal[3 * i], this.normal[3 * i + 1], this.normal[3 * i + 2]];
      const n2 = dot(nrm, nrm);
      if (n2 > 0.25 && dot(nrm, toEye) < o.backface_cos * Math.sqrt(n2)) continue;
      if (this.count[i] === 0) continue;
      cams.length = 0;
      for (let j = 0; j < this.count[i]; ++j) {
        const ci = this.facetCameras[this.first[i] + j];
        cams.push([angleBetween(normalize(sub(this.camCentres[ci], c)), toEye), ci]);
      }
      cams.sort((a, b) => a[0] - b[0] || a[1] - b[1]);
      const keep = Math.min(k + 1, cams.length);
      for (let j = 0; j < keep; ++j) angles[j] = cams[j][0];
      w.fill(0);
      const blended = blendWeights(angles, cams.length, k, w);
      const used = pruneWeights(w, blended, o.min_weight);
      const e = 13 * drawn;
      F[e] = c[0]; F[e + 1] = c[1]; F[e + 2] = c[2]; F[e + 3] = this.size[i];
      F[e + 4] = this.rel[i];
      for (let j = 0; j < 4; ++j) {
        I[e + 5 + j] = j < used ? cams[j][1] : -1;
        F[e + 9 + j] = j < used ? w[j] : 0;
      }
      list.push([Math.fround(dist * dist), drawn]);
      ++drawn;
    }
    // Front to back, as s2r render (ties keep their order).
    list.sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    const sorted = new ArrayBuffer(drawn * 52);
    const S = new Uint32Array(sorted), U = new Uint32Array(this.instances);
    for (let j = 0; j < drawn; ++j) S.set(U.subarray(13 * list[j][1], 13 * list[j][1] + 13), 13 * j);
    return { buffer: sorted, count: drawn };
  }

  draw(v) {
    const gl = this.gl, u = this.u, o = this.h.draw;
    const t0 = performance.now();
    const canvas = gl.canvas;
    if (canvas.width !== v.K.width || canvas.height !== v.K.height) { canvas.width = v.K.width; canvas.height = v.K.height; }
    gl.viewport(0, 0, v.K.width, v.K.height);
    const bg = this.h.background;
    gl.clearColor(bg[0], bg[1], bg[2], 1);
    gl.clearDepth(1);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    gl.disable(gl.BLEND);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    const [near, far] = this.depthRange(v);
    const sel = this.select(v, near);
    gl.useProgram(this.prog);
    gl.uniformMatrix4fv(u.u_view_cfw, false, cfwMatrix(v));
    gl.uniform4f(u.u_view_k, v.K.fx, v.K.fy, v.K.cx, v.K.cy);
    const d = v.K.dist || [0, 0, 0, 0, 0];
    gl.uniform4f(u.u_view_d, d[0], d[1], d[2], d[3]);
    gl.uniform1f(u.u_view_k3, d[4]);
    gl.uniform2f(u.u_view_size, v.K.width, v.K.height);
    gl.uniform2f(u.u_near_far, near, far);
    gl.uniform1i(u.u_view_distort, d.some((x) => x !== 0) ? 1 : 0);
    gl.uniform3f(u.u_eye, v.eye[0], v.eye[1], v.eye[2]);
    const up = scale(v.down, -1);
    gl.uniform3f(u.u_up, up[0], up[1], up[2]);
    gl.uniform1f(u.u_scale, Math.max(o.billboard_scale, Math.sqrt(3)));
    gl.uniform1i(u.u_clip, o.depth_clip ? 1 : 0);
    gl.uniform1f(u.u_clip_scale, o.clip_scale);
    gl.uniform1i(u.u_probe, this.nearestCamera(v));
    gl.uniform1i(u.u_refine, Math.max(0, o.refine_steps));
    gl.uniform1i(u.u_clip_fuzzy, o.clip_fuzzy || !this.hasReliable ? 1 : 0);
    gl.uniform3f(u.u_view_forward, v.fwd[0], v.fwd[1], v.fwd[2]);
    gl.uniform1f(u.u_view_focal, Math.sqrt(v.K.fx * v.K.fy));
    gl.uniform1f(u.u_px_error, Math.max(0, o.pixel_error));
    gl.uniform1i(u.u_color, 0);
    gl.uniform1i(u.u_dist, 1);
    gl.uniform1i(u.u_cams, 2);
    gl.uniform2f(u.u_tex_size, this.h.texture_width, this.h.texture_height);
    gl.bindVertexArray(this.vao);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.vbo);
    gl.bufferData(gl.ARRAY_BUFFER, sel.buffer, gl.STREAM_DRAW);
    if (sel.count) gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, sel.count);
    gl.bindVertexArray(null);
    gl.finish();
    const ms = performance.now() - t0;
    status(`${sel.count.toLocaleString()} of ${this.n.toLocaleString()} facets, ${ms.toFixed(0)} ms`);
    return { drawn: sel.count, ms };
  }
}

// ---- orbit, pan, zoom, touch ----
function orbitControls(canvas, state, redraw) {
  const rotate = (v, axis, ang) => {  // Rodrigues
    const c = Math.cos(ang), s = Math.sin(ang);
    return add(add(scale(v, c), scale(cross(axis, v), s)), scale(axis, dot(axis, v) * (1 - c)));
  };
  const orbit = (dx, dy) => {
    // Turn about the world's up through the target, then tilt about the view's right.
    const v = state.view, t = state.target, up = state.up;
    const a = -dx * 0.008, b = dy * 0.008;
    let rel = sub(v.eye, t);
    const turn = (vec) => rotate(vec, up, a);
    rel = turn(rel); v.right = turn(v.right); v.down = turn(v.down); v.fwd = turn(v.fwd);
    const right = v.right;
    const tilt = (vec) => rotate(vec, right, b);
    rel = tilt(rel); v.down = tilt(v.down); v.fwd = tilt(v.fwd);
    v.eye = add(t, rel);
  };
  const pan = (dx, dy) => {
    const v = state.view;
    const d = norm(sub(v.eye, state.target)) / v.K.fx;
    const move = add(scale(v.right, -dx * d), scale(v.down, -dy * d));
    v.eye = add(v.eye, move);
    state.target = add(state.target, move);
  };
  const zoom = (f) => {
    const v = state.view;
    v.eye = add(state.target, scale(sub(v.eye, state.target), f));
  };
  let last = null, button = 0;
  const pointers = new Map();
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('pointerdown', (e) => {
    canvas.setPointerCapture(e.pointerId);
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    last = [e.clientX, e.clientY];
    button = e.button === 2 || e.shiftKey ? 2 : 0;
  });
  canvas.addEventListener('pointerup', (e) => { pointers.delete(e.pointerId); last = null; });
  canvas.addEventListener('pointercancel', (e) => { pointers.delete(e.pointerId); last = null; });
  canvas.addEventListener('pointermove', (e) => {
    if (!pointers.has(e.pointerId)) return;
    if (pointers.size === 2) {  // pinch: zoom by the change of spread, pan by the centre's motion
      const [a, b] = [...pointers.values()];
      const before = Math.hypot(a[0] - b[0], a[1] - b[1]);
      const cx = (a[0] + b[0]) / 2, cy = (a[1] + b[1]) / 2;
      pointers.set(e.pointerId, [e.clientX, e.clientY]);
      const [c, d] = [...pointers.values()];
      const after = Math.hypot(c[0] - d[0], c[1] - d[1]);
      if (before > 0 && after > 0) zoom(before / after);
      pan((c[0] + d[0]) / 2 - cx, (c[1] + d[1]) / 2 - cy);
      redraw();
      return;
    }
    pointers.set(e.pointerId, [e.clientX, e.clientY]);
    if (!last) return;
    const dx = e.clientX - last[0], dy = e.clientY - last[1];
    last = [e.clientX, e.clientY];
    if (button === 2) pan(dx, dy); else orbit(dx, dy);
    redraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    zoom(Math.exp(e.deltaY * 0.001));
    redraw();
  }, { passive: false });
}

function cameraView(c, width, height) {
  // The capture camera's pose and field of view at the window's size (pinhole).
  const s = Math.min(width / c.K.width, height / c.K.height);
  const K = { width, height, fx: c.K.fx * s, fy: c.K.fy * s, cx: (width - 1) / 2, cy: (height - 1) / 2, dist: [0, 0, 0, 0, 0] };
  return { K, right: [...c.right], down: [...c.down], fwd: [...c.fwd], eye: [...c.centre] };
}

async function main() {
  const params = new URLSearchParams(location.search);
  const header = await (await fetch('model.json')).json();
  if (header.format !== 's2r.web' || header.version !== 1) throw new Error('model.json: not an s2r.web version 1 model');
  const total = header.payloads.reduce((s, p) => s + p.bytes, 0);
  let got = 0;
  const bar = $('progress').firstElementChild, label = $('progress').lastElementChild;
  const onBytes = (n) => {
    got += n;
    bar.style.width = `${(100 * got / Math.max(1, total)).toFixed(1)}%`;
    label.textContent = `loading ${(got / 1048576).toFixed(1)} of ${(total / 1048576).toFixed(1)} MiB`;
  };
  const payloads = {};
  await Promise.all(header.payloads.map(async (p) => {
    payloads[p.name] = await fetchBytes(p.file, onBytes);
    if (payloads[p.name].byteLength !== p.bytes) throw new Error(`${p.file}: ${payloads[p.name].byteLength} bytes, expected ${p.bytes}`);
  }));
  $('progress').style.display = 'none';
  const viewer = new Viewer(header, payloads);
  const canvas = $('view');
  const b = header.bounds;
  const state = { target: scale(add(b.min, b.max), 0.5), up: header.up, view: null };
  let fixed = null;
  if (params.get('view')) {
    const vj = await (await fetch(params.get('view'))).json();
    if (vj.format !== 's2r.view') throw new Error(`${params.get('view')}: not an s2r.view file`);
    fixed = viewFromPose(vj.intrinsics, vj.world_from_camera);
    $('bar').style.display = 'none';
  }
  const size = () => [Math.max(64, window.innerWidth), Math.max(64, window.innerHeight)];
  const first = () => (header.cameras.length ? cameraView(header.cameras[0], ...size())
    : viewFromPose({ width: size()[0], height: size()[1], fx: size()[0], fy: size()[0], cx: size()[0] / 2, cy: size()[1] / 2 },
      [1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 1]));
  state.view = fixed || first();
  let pending = false;
  const redraw = () => {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => {
      pending = false;
      const r = viewer.draw(state.view);
      window.s2r.frames += 1;
      window.s2r.lastFrameMs = r.ms;
      window.s2r.drawn = r.drawn;
    });
  };
  window.s2r = { frames: 0, ready: false, header };
  const sel = $('cameras');
  header.cameras.forEach((c, i) => {
    const o = document.createElement('option');
    o.value = String(i);
    o.textContent = `camera ${i} (frame ${c.session_frame})`;
    sel.appendChild(o);
  });
  sel.addEventListener('change', () => {
    if (sel.value === '') return;
    state.view = cameraView(header.cameras[Number(sel.value)], ...size());
    state.target = scale(add(b.min, b.max), 0.5);
    redraw();
  });
  $('reset').addEventListener('click', () => { state.view = first(); state.target = scale(add(b.min, b.max), 0.5); redraw(); });
  window.addEventListener('keydown', (e) => { if (e.key === 'r' || e.key === 'R') $('reset').click(); });
  window.addEventListener('resize', () => {
    if (fixed) return;
    const [w, h] = size();
    const s = w / state.view.K.width;
    Object.assign(state.view.K, { width: w, height: h, fx: state.view.K.fx * s, fy: state.view.K.fy * s, cx: (w - 1) / 2, cy: (h - 1) / 2 });
    redraw();
  });
  orbitControls(canvas, state, redraw);
  const r = viewer.draw(state.view);
  window.s2r.frames = 1;
  window.s2r.lastFrameMs = r.ms;
  window.s2r.drawn = r.drawn;
  window.s2r.ready = true;
}

main().catch((e) => fail(e.message || String(e)));
