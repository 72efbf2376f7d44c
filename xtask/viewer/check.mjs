// node check.mjs GLB OUT.png WIDTH HEIGHT STOPS
// Serves this folder and the GLB's folder over HTTP, renders the GLB in headless Chromium
// (Debian's /usr/bin/chromium, or $CHROMIUM) with page.html and writes the canvas as a PNG.
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const [glb, out, w, h, stops] = process.argv.slice(2);
const here = path.dirname(fileURLToPath(import.meta.url));
const types = { '.html': 'text/html', '.js': 'text/javascript', '.glb': 'model/gltf-binary' };
const server = http.createServer((req, res) => {
  const url = decodeURIComponent(new URL(req.url, 'http://x').pathname);
  const file = url === '/scene.glb' ? glb : path.join(here, path.normalize(url));
  fs.readFile(file, (err, data) => {
    if (err) { res.writeHead(404); res.end(); return; }
    res.writeHead(200, { 'Content-Type': types[path.extname(file)] || 'application/octet-stream' });
    res.end(data);
  });
});
await new Promise((r) => server.listen(0, '127.0.0.1', r));
const port = server.address().port;
const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
  args: ['--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
});
try {
  const page = await browser.newPage({ viewport: { width: Number(w), height: Number(h) } });
  await page.goto(`http://127.0.0.1:${port}/page.html?glb=/scene.glb&w=${w}&h=${h}&exposure=${stops}`);
  await page.waitForFunction(() => window.done || window.failed, null, { timeout: 120000 });
  const failed = await page.evaluate(() => window.failed);
  if (failed) throw new Error(failed);
  await page.locator('canvas').screenshot({ path: out });
} finally {
  await browser.close();
  server.close();
}
