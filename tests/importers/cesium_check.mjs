// CesiumJS on a terrachunk tileset (DESIGN.md promise 5), in Debian's
// headless Chromium driven by playwright-core, served from 127.0.0.1 only.
//
//   node cesium_check.mjs TILESET_DIR [--dem DEM.tif] [--screenshot docs/cesium.png] [--close-shot PNG]
//
// Loads tileset.json with Cesium3DTileset.fromUrl (no Cesium ion, no imagery,
// no terrain: the bare WGS 84 ellipsoid), with maximumScreenSpaceError = the
// tileset's tau_max_px, then:
// - no tile fails to load (tileFailed), the page throws nothing, and no
//   request leaves the loopback server;
// - seen from afar, the tileset sits where its georeference says: the
//   bounding sphere's centre, as a longitude/latitude, is within 2 m (and
//   2 px on screen) of the grid centre that proj4js (an independent
//   projection library) computes from extras.terrachunk.georef, and the
//   north-west corner sample lands within 1 m + 0.5 % of its distance of
//   where proj4js puts it (a planar tileset's grid corner; a curved one's
//   true place in its frame: see src/geodesy/);
// - with the camera close to a deepest-level tile, refinement reaches the
//   deepest level (tileVisible events of the last frame, by the tiles'
//   extras.terrachunk.level);
// - there, at three DEM samples inside that tile (heights read from the
//   GeoTIFF by geotiff.js, places by proj4js), the terrain Cesium draws
//   (scene.clampToHeight along the normal) is within the leaf δ of the DEM.
// Prints a short report (with the glTF extensions the target tile requires,
// so that a --compress run shows what Cesium decoded); exits 1 on any failure.

import fs from "node:fs";
import http from "node:http";
import path from "node:path";
import { fileURLToPath } from "node:url";

import { fromFile } from "geotiff";
import { chromium } from "playwright-core";
import proj4 from "proj4";

const here = path.dirname(fileURLToPath(import.meta.url));
const args = process.argv.slice(2);
const tilesetDir = path.resolve(args[0] ?? "");
const opt = (name) => {
  const i = args.indexOf(name);
  return i >= 0 ? args[i + 1] : undefined;
};
const shot = opt("--screenshot");
const demFile = opt("--dem");
const closeShot = opt("--close-shot");
const chromiumPath = process.env.CHROMIUM ?? "/usr/bin/chromium";
if (!fs.existsSync(path.join(tilesetDir, "tileset.json"))) {
  console.error(`usage: node cesium_check.mjs TILESET_DIR [--screenshot PNG]; no tileset.json in ${tilesetDir}`);
  process.exit(2);
}
const failures = [];
const fail = (m) => failures.push(m);

// ---- What the tileset says, and where proj4js puts it -------------------
// With each external tileset (a tile whose content is a .json beside
// tileset.json) read in place of the tile that refers to it; Cesium fetches
// them itself.
const readJson = (name) => JSON.parse(fs.readFileSync(path.join(tilesetDir, name), "utf8"));
const inline = (t) => {
  if (t.content?.uri?.endsWith(".json")) return inline(readJson(t.content.uri).root);
  if (t.children) t.children = t.children.map(inline);
  return t;
};
const ts = readJson("tileset.json");
ts.root = inline(ts.root);
const ex = ts.extras.terrachunk;
const deepest = Math.max(...allTiles(ts.root).map((t) => t.extras.terrachunk.level));

function allTiles(t, out = []) {
  if (t.content) out.push(t);
  (t.children ?? []).forEach((c) => allTiles(c, out));
  return out;
}

// proj4 definition of the source CRS, or null when there is no independent
// expectation for it.
function proj4Def(crs) {
  if (crs.geographic) {
    const e = crs.geographic.epsg;
    return e == null || [4326, 4269, 4258].includes(e) ? "WGS84" : null;
  }
  const e = crs.projected?.epsg;
  if (e == null) return null;
  if (e >= 32601 && e <= 32660) return `+proj=utm +zone=${e - 32600} +datum=WGS84 +units=m +no_defs`;
  if (e >= 32701 && e <= 32760) return `+proj=utm +zone=${e - 32700} +south +datum=WGS84 +units=m +no_defs`;
  if (e >= 26901 && e <= 26923) return `+proj=utm +zone=${e - 26900} +datum=NAD83 +units=m +no_defs`;
  // NAD27 UTM with the CONUS mean shift terrachunk also uses (its code is
  // independent; its datum parameters are not, and NADCON would differ by metres).
  if (e >= 26703 && e <= 26722) return `+proj=utm +zone=${e - 26700} +ellps=clrk66 +towgs84=-8,160,176,0,0,0,0 +units=m +no_defs`;
  if (e >= 25828 && e <= 25838) return `+proj=utm +zone=${e - 25800} +ellps=GRS80 +towgs84=0,0,0 +units=m +no_defs`;
  if ([3857, 3785, 900913, 102100, 102113].includes(e)) return "EPSG:3857";
  return null;
}

const g = ex.georef;
const def = proj4Def(g.crs);
const toLonLat = def && def !== "WGS84" ? (p) => proj4(def, "WGS84", p) : (p) => p;
const [w, h] = [ex.grid.width, ex.grid.height];
const centreSrc = [g.origin[0] + (g.step[0] * (w - 1)) / 2, g.origin[1] + (g.step[1] * (h - 1)) / 2];
const expectCentre = def ? toLonLat(centreSrc) : null;
const expectCorner = def ? toLonLat(g.origin) : null;
const placed = Array.isArray(ts.root.transform);

// Where the tileset has the north-west corner sample at height 0: grid
// metres (0, 0, 0) in the planar frame; in the curved frame its true place,
// the ENU coordinates (at the placement's centre) of its WGS 84 position
// as proj4js gives it, shifted by the placement's centre.
function ecef(lonDeg, latDeg, h) {
  const a = 6378137.0, f = 1 / 298.257223563, e2 = f * (2 - f);
  const [lon, lat] = [lonDeg, latDeg].map((d) => (d * Math.PI) / 180);
  const n = a / Math.sqrt(1 - e2 * Math.sin(lat) ** 2);
  return [(n + h) * Math.cos(lat) * Math.cos(lon), (n + h) * Math.cos(lat) * Math.sin(lon), (n * (1 - e2) + h) * Math.sin(lat)];
}
function cornerLocal() {
  const p = ex.placement;
  if (!p || p.frame !== "curved" || !expectCorner) return [0, 0, 0];
  const [lon, lat] = [p.lon_deg, p.lat_deg].map((d) => (d * Math.PI) / 180);
  const o = ecef(p.lon_deg, p.lat_deg, p.height_m);
  const q = ecef(expectCorner[0], expectCorner[1], 0);
  const d = q.map((v, k) => v - o[k]);
  const east = [-Math.sin(lon), Math.cos(lon), 0];
  const north = [-Math.sin(lat) * Math.cos(lon), -Math.sin(lat) * Math.sin(lon), Math.cos(lat)];
  const up = [Math.cos(lat) * Math.cos(lon), Math.cos(lat) * Math.sin(lon), Math.sin(lat)];
  const dot = (u) => u[0] * d[0] + u[1] * d[1] + u[2] * d[2];
  return [p.centre[0] + dot(east), p.centre[1] + dot(north), dot(up)];
}

// The deepest-level tile nearest the grid centre: the close view's target.
const cx = ((w - 1) / 2) * ex.spacing_m[0];
const cy = (-(h - 1) / 2) * ex.spacing_m[1];
const target = allTiles(ts.root)
  .filter((t) => t.extras.terrachunk.level === deepest)
  .map((t) => [Math.hypot(t.boundingVolume.box[0] - cx, t.boundingVolume.box[1] - cy), t.extras.terrachunk])
  .sort((a, b) => a[0] - b[0])[0][1];
const targetKey = `${target.level}/${target.x}/${target.y}`;
// The chunks from the top down to the target.
const keyOf = (t) => t.extras?.terrachunk && `${t.extras.terrachunk.level}/${t.extras.terrachunk.x}/${t.extras.terrachunk.y}`;
function chainTo(t, path = []) {
  const here = keyOf(t) ? [...path, keyOf(t)] : path;
  if (keyOf(t) === targetKey) return here;
  for (const c of t.children ?? []) {
    const found = chainTo(c, here);
    if (found) return found;
  }
  return null;
}
const targetChain = chainTo(ts.root);

// The glTF extensions the target tile requires (KHR_mesh_quantization and
// EXT_ or KHR_meshopt_compression with --compress): what Cesium had to decode.
function glbJson(file) {
  const b = fs.readFileSync(file);
  return JSON.parse(b.subarray(20, 20 + b.readUInt32LE(12)).toString("utf8"));
}
const targetUri = allTiles(ts.root).find((t) => {
  const e = t.extras.terrachunk;
  return `${e.level}/${e.x}/${e.y}` === targetKey;
}).content.uri;
const required = glbJson(path.join(tilesetDir, targetUri)).extensionsRequired ?? [];

// Three samples inside the target tile (0.3, 0.55 and 0.8 of the way
// along its diagonal, mostly not vertices) with their heights read from the DEM by
// geotiff.js, where the DEM is a GeoTIFF and its CRS has a proj4js
// expectation: Cesium's terrain there must lie within the leaf δ of them.
async function readBackSamples() {
  if (!demFile || !def || !/\.tiff?$/i.test(demFile)) return [];
  const fp = glbJson(path.join(tilesetDir, targetUri)).nodes[0].extras.terrachunk.footprint;
  const image = await (await fromFile(demFile)).getImage();
  const nodata = image.getGDALNoData();
  const out = [];
  for (const t of [0.3, 0.55, 0.8]) {
    const j = Math.round(fp.x0 + t * (fp.x1 - fp.x0));
    const i = Math.round(fp.z0 + t * (fp.z1 - fp.z0));
    const [band] = await image.readRasters({ window: [j, i, j + 1, i + 1] });
    const h = Number(band[0]);
    if (!Number.isFinite(h) || h === nodata) continue;
    out.push({ i, j, h, lonLat: toLonLat([g.origin[0] + g.step[0] * j, g.origin[1] + g.step[1] * i]) });
  }
  return out;
}
const samples = await readBackSamples();

// ---- A loopback-only static server --------------------------------------
const roots = {
  "/cesium/": path.join(here, "node_modules", "cesium", "Build", "Cesium"),
  "/tileset/": tilesetDir,
};
const types = { ".html": "text/html", ".js": "text/javascript", ".css": "text/css", ".json": "application/json", ".glb": "model/gltf-binary", ".png": "image/png", ".svg": "image/svg+xml", ".wasm": "application/wasm" };
const missing = [];
let served = 0;
const server = http.createServer((req, res) => {
  const url = decodeURIComponent(new URL(req.url, "http://127.0.0.1").pathname);
  let file = null;
  if (url === "/" || url === "/index.html") file = path.join(here, "cesium_page.html");
  for (const [prefix, dir] of Object.entries(roots)) {
    if (url.startsWith(prefix)) {
      const f = path.normalize(path.join(dir, url.slice(prefix.length)));
      if (f.startsWith(dir)) file = f;
    }
  }
  if (!file || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
    missing.push(url);
    res.writeHead(404).end();
    return;
  }
  served++;
  res.writeHead(200, { "Content-Type": types[path.extname(file)] ?? "application/octet-stream" });
  fs.createReadStream(file).pipe(res);
});
await new Promise((r) => server.listen(0, "127.0.0.1", r));
const origin = `http://127.0.0.1:${server.address().port}`;

// ---- The browser ----------------------------------------------------------
const browser = await chromium.launch({
  executablePath: chromiumPath,
  args: [
    "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
    "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
    "--disable-quic", "--disable-default-apps",
  ],
});
const outside = [];
const consoleErrors = [];
let report;
let close;
let placement = null;
try {
  const page = await browser.newPage({ viewport: { width: 800, height: 500 } });
  await page.route("**/*", (route) => {
    const u = route.request().url();
    if (u.startsWith(origin) || u.startsWith("data:") || u.startsWith("blob:")) return route.continue();
    outside.push(u);
    return route.abort();
  });
  page.on("console", (m) => { if (m.type() === "error") consoleErrors.push(m.text()); });
  page.on("pageerror", (e) => consoleErrors.push(String(e)));
  await page.goto(`${origin}/`);
  await page.waitForFunction(() => window.tc !== undefined, null, { timeout: 60_000 });

  const settle = async (label) => {
    // Loaded and nothing pending over 10 rendered frames in a row, counted
    // in frames, not wall time: under load a SwiftShader frame can take
    // longer than a poll, and the first status after a camera move still
    // describes the old view.
    const t0 = Date.now();
    const start = (await page.evaluate(() => window.tc.status())).frames;
    let calmSince = start;
    for (;;) {
      const s = await page.evaluate(() => window.tc.status());
      if (!(s.tilesLoaded && s.pending === 0 && s.processing === 0)) calmSince = s.frames;
      else if (s.frames - calmSince >= 10 && s.frames - start >= 10) return;
      if (Date.now() - t0 > 120_000) {
        fail(`${label}: tiles still loading after 120 s (${JSON.stringify(s)})`);
        return;
      }
      await page.waitForTimeout(50);
    }
  };

  await page.evaluate(([u, sse]) => window.tc.load(u, sse), ["/tileset/tileset.json", ex.tau_max_px]);
  await page.evaluate(() => window.tc.overview());
  await settle("overview");
  const far = await page.evaluate(() => window.tc.report());
  if (def && placed) {
    placement = await page.evaluate(([a, b, c]) => window.tc.placement(a, b, c), [expectCentre, expectCorner, cornerLocal()]);
  }
  if (shot) await page.screenshot({ path: shot });

  // Down the chain, one external tileset at a time.
  for (let step = 0; step <= targetChain.length; step++) {
    close = await page.evaluate((c) => window.tc.closeTo(c), targetChain);
    await settle(close.reached ? "close view" : `close to ${close.at}`);
    if (close.reached) break;
  }
  if (!close.reached) fail(`the camera never reached ${targetKey}: Cesium has no deeper tile of its chain than ${close.at}`);
  report = await page.evaluate(() => window.tc.report());
  report.farVisibleByLevel = far.visibleByLevel;
  const heights = await page.evaluate((pts) => window.tc.heightsAt(pts), samples.map((s) => s.lonLat));
  samples.forEach((s, k) => { s.cesium = heights[k]; });
  if (closeShot) await page.screenshot({ path: closeShot });
} finally {
  await browser.close();
  server.close();
}

// ---- Verdict -----------------------------------------------------------------
const levelsShown = Object.keys(report.visibleByLevel).map(Number);
if (report.failed.length) fail(`${report.failed.length} tiles failed to load: ${report.failed.slice(0, 3).join("; ")}`);
if (report.errors.length) fail(`page errors: ${report.errors.slice(0, 3).join("; ")}`);
if (consoleErrors.length) fail(`console errors: ${consoleErrors.slice(0, 3).join("; ")}`);
if (outside.length) fail(`${outside.length} requests tried to leave 127.0.0.1: ${outside.slice(0, 3).join(", ")}`);
if (missing.length) fail(`${missing.length} requests not found: ${missing.slice(0, 3).join(", ")}`);
if (!levelsShown.includes(deepest)) fail(`close to ${targetKey}, the deepest level shown is ${Math.max(...levelsShown)}, not ${deepest}`);
if (!report.visible.includes(targetKey)) fail(`close view does not show its target ${targetKey}`);
if (def && !placed) fail(`the georeference (${JSON.stringify(g.crs)}) can be placed, but tileset.json has no root transform`);
if (!def && placed) console.log(`cesium: root transform present, but no independent proj4 expectation for ${JSON.stringify(g.crs)}`);
if (placement) {
  const cornerDist = Math.hypot(cx, cy);
  // A planar tileset's box is the grid's, centred on its centre. A curved
  // one's holds the grid turned by its convergence and bent onto the Earth
  // (and where the DEM has data), its centre below the surface, where
  // degrees narrow northwards: it may lie aside by up to a hundredth of the
  // grid's size (California's 7° × 4°: 2.8 km at 379 km).
  const curved = ex.placement?.frame === "curved";
  const [centreM, centrePx] = curved ? [2 + 0.01 * cornerDist, Infinity] : [2, 2];
  if (!(placement.centreErrorM <= centreM)) fail(`bounding sphere centre ${placement.centreErrorM.toFixed(3)} m from the grid centre`);
  if (!(placement.centreErrorPx <= centrePx)) fail(`bounding sphere centre ${placement.centreErrorPx?.toFixed(2)} px from the grid centre on screen`);
  if (!(placement.cornerErrorM <= 1 + 0.005 * cornerDist)) fail(`north-west corner ${placement.cornerErrorM.toFixed(2)} m from where proj4js puts it`);
}

// A sample's height as Cesium draws the terrain: within the leaf δ of the
// DEM (and a centimetre for the depth read-back).
const readBackTol = ex.max_error_m * ex.vertical_scale + 0.01;
for (const s of samples) {
  const d = s.cesium == null ? Infinity : Math.abs(s.cesium - s.h * ex.vertical_scale);
  if (!(d <= readBackTol)) fail(`terrain at sample (${s.i}, ${s.j}) reads ${s.cesium} m in Cesium, the DEM ${s.h} m (allowed ${readBackTol} m)`);
}
if (demFile && def && /\.tiff?$/i.test(demFile) && samples.length === 0) fail("no DEM sample to read back");

const fmt = (o) => Object.entries(o).map(([l, n]) => `L${l}:${n}`).join(" ");
const version = JSON.parse(fs.readFileSync(path.join(here, "node_modules", "cesium", "package.json"), "utf8")).version;
console.log(`cesium ${version} in ${(await browser.version?.()) ?? "chromium"}, tileset ${ex.source.join(",")} (${deepest + 1} levels, tau ${ex.tau_max_px} px)`);
console.log(`cesium tiles loaded by level ${fmt(report.loadedByLevel)}; overview shows ${fmt(report.farVisibleByLevel)}`);
console.log(`cesium content: ${targetUri} requires ${required.length ? required.join(", ") : "no glTF extension"}`);
console.log(`cesium close to ${targetKey} (range ${close.range.toFixed(0)} m, refinement needs < ${close.dMax.toFixed(0)} m): shows ${fmt(report.visibleByLevel)}; ${report.failed.length} tile failures, ${served} files served, ${outside.length} outside requests`);
if (placement) {
  console.log(
    `cesium placement: sphere centre lon/lat ${placement.centre[0].toFixed(7)}, ${placement.centre[1].toFixed(7)} vs proj4js ${expectCentre[0].toFixed(7)}, ${expectCentre[1].toFixed(7)}: ` +
      `${placement.centreErrorM.toFixed(3)} m, ${placement.centreErrorPx.toFixed(2)} px; NW corner ${placement.cornerErrorM.toFixed(3)} m off at ${(Math.hypot(cx, cy) / 1000).toFixed(1)} km from the centre`,
  );
} else {
  console.log(`cesium placement: not checked (${placed ? "no proj4 expectation" : "no root transform"} for ${JSON.stringify(g.crs)})`);
}
for (const s of samples) {
  console.log(
    `cesium read-back at sample (${s.i}, ${s.j}) lon/lat ${s.lonLat[0].toFixed(6)}, ${s.lonLat[1].toFixed(6)}: ` +
      `terrain ${s.cesium?.toFixed(3)} m, DEM ${s.h.toFixed(3)} m, off by ${(s.cesium - s.h).toFixed(3)} m (leaf δ ${ex.max_error_m} m)`,
  );
}
for (const f of failures) console.log(`cesium FAIL ${f}`);
console.log(`cesium: ${failures.length} failures`);
process.exit(failures.length ? 1 : 0);
