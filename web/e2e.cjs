#!/usr/bin/env node
// Drive `fracture view` in headless Chromium (Debian's chromium, through playwright-core) and
// report what the page did. Used by tests/test_view_e2e.py and to take the README screenshot.
//
//   node web/e2e.cjs SCRIPT.json > RESULT.json
//
// SCRIPT: {"url": "...", "modules": "build/web/node_modules", "chromium": "/usr/bin/chromium",
//          "width": 1280, "height": 800, "actions": [...]}
// Actions, run in order (each appends one entry to "results"):
//   {"do": "wait_ready"}                                   the asset is loaded
//   {"do": "set", "id": "magnitude", "value": 2.5}         fill an input and fire "change"
//   {"do": "check", "id": "bonds", "value": true}          tick or untick a checkbox
//   {"do": "select", "id": "color-mode", "value": "mode-0"}
//   {"do": "click_model", "point": [x, y, z]}              real mouse click where the model point is drawn
//   {"do": "wait_animation"}                               the groups have landed
//   {"do": "wait", "ms": 500}
//   {"do": "mouse", "x": 10, "y": 10}                      move the mouse (e.g. off the object: no tooltip)
//   {"do": "screenshot", "path": "out.png"}
//   {"do": "touch", "paths": ["a", "b"]}                   bump mtimes (a re-bake in miniature)
//   {"do": "wait_reload", "after": N}                      fractureTest.reloads > N
//   {"do": "eval", "expr": "fractureTest.model()"}         any expression, result returned
// The result: {"results": [...], "console_errors": [...], "webgl": "..."}.

const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');

// headless: true below adds --headless.
const FLAGS = ['--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--disable-sync', '--no-first-run',
  // No GPU here: WebGL runs on SwiftShader, which recent Chromium only enables when asked.
  '--use-angle=swiftshader', '--enable-unsafe-swiftshader'];

async function run(script) {
  const { chromium } = require(path.resolve(script.modules, 'playwright-core'));
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'fracture-view-chromium-'));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: script.chromium || '/usr/bin/chromium', headless: true, args: FLAGS,
    viewport: { width: script.width || 1280, height: script.height || 800 }, offline: false,
  });
  const consoleErrors = [];
  const results = [];
  try {
    const page = context.pages()[0] || await context.newPage();
    page.on('console', (msg) => { if (msg.type() === 'error') consoleErrors.push(msg.text()); });
    page.on('pageerror', (err) => consoleErrors.push(String(err)));
    // Nothing but the local server may be fetched: the page must work offline.
    await page.route('**/*', (route) => {
      const url = new URL(route.request().url());
      if (url.origin === new URL(script.url).origin) return route.continue();
      consoleErrors.push(`blocked external request: ${url.href}`);
      return route.abort();
    });
    await page.goto(script.url);
    const webgl = await page.evaluate(() => {
      const gl = document.createElement('canvas').getContext('webgl2');
      return gl ? gl.getParameter(gl.RENDERER) : null;
    });
    for (const action of script.actions) results.push(await act(page, action));
    return { results, console_errors: consoleErrors, webgl };
  } finally {
    await context.close();
    fs.rmSync(profile, { recursive: true, force: true });
  }
}

async function act(page, action) {
  const timeout = action.timeout_ms || 60000;
  switch (action.do) {
    case 'wait_ready':
      await page.waitForFunction(() => window.fractureTest && window.fractureTest.ready, null, { timeout });
      return page.evaluate(() => ({ asset: fractureTest.asset, model: fractureTest.model(), reloads: fractureTest.reloads }));
    case 'set':
      await page.fill(`#${action.id}`, String(action.value));
      await page.dispatchEvent(`#${action.id}`, 'change');
      return page.inputValue(`#${action.id}`);
    case 'check':
      await page.setChecked(`#${action.id}`, Boolean(action.value));
      return page.isChecked(`#${action.id}`);
    case 'select':
      await page.selectOption(`#${action.id}`, String(action.value));
      return page.inputValue(`#${action.id}`);
    case 'click_model': {
      const screen = await page.evaluate((p) => fractureTest.screenPoint(p), action.point);
      await page.mouse.click(screen.x, screen.y);
      const hit = await page.evaluate(() => fractureTest.lastHit);
      return { screen, hit };
    }
    case 'wait_animation':
      await page.waitForFunction(() => fractureTest.animationDone, null, { timeout });
      return true;
    case 'wait':
      await page.waitForTimeout(action.ms);
      return true;
    case 'mouse':
      await page.mouse.move(action.x, action.y);
      return true;
    case 'screenshot':
      await page.screenshot({ path: action.path });
      return action.path;
    case 'touch': {
      const now = new Date();
      for (const p of action.paths) fs.utimesSync(p, now, now);
      return true;
    }
    case 'wait_reload':
      await page.waitForFunction((n) => fractureTest.reloads > n && fractureTest.ready, action.after, { timeout });
      return page.evaluate(() => ({ asset: fractureTest.asset, reloads: fractureTest.reloads, version: fractureTest.version }));
    case 'eval':
      return page.evaluate(action.expr);
    default:
      throw new Error(`unknown action ${JSON.stringify(action.do)}`);
  }
}

run(JSON.parse(fs.readFileSync(process.argv[2], 'utf-8')))
  .then((out) => process.stdout.write(JSON.stringify(out) + '\n'))
  .catch((err) => {
    process.stderr.write(`e2e: ${err && err.stack ? err.stack : err}\n`);
    process.exit(1);
  });
