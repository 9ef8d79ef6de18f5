// Drives Debian's chromium (playwright-core, no browser download) against the gateway's live page
// for tests/gateway_web_browser.rs. Prints one JSON object per line on stdout; the Rust test makes
// every assertion. Env: PAGE_URL, SHOT_DIR, FAULT_CHANNEL, CHROMIUM (default /usr/bin/chromium).
import { chromium } from "playwright-core";

const out = (o) => console.log(JSON.stringify(o));
const url = process.env.PAGE_URL;
const shots = process.env.SHOT_DIR;
const channel = process.env.FAULT_CHANNEL;

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
  args: ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update"],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 1000 } });
  const seen = new Map();
  page.on("response", async (r) => {
    if (new URL(r.url()).pathname === "/status" && r.ok()) {
      try { const j = await r.json(); seen.set(j.cycles, j); } catch (e) { /* page navigated */ }
    }
  });
  const errors = [];
  page.on("pageerror", (e) => errors.push(String(e)));
  // The page has no favicon: the browser's own /favicon.ico probe (404) is not the page's error.
  page.on("console", (m) => {
    const at = m.location().url || "";
    if (m.type() === "error" && !at.endsWith("/favicon.ico")) errors.push(`${m.text()} (${at})`);
  });
  await page.goto(url);
  await page.waitForSelector("[data-axis] .applied", { timeout: 60000 });
  for (let i = 0; i < 6; i++) {
    const shown = await page.evaluate(() => ({
      cycles: Number(document.body.dataset.cycles),
      banner: document.querySelector("#banner").textContent,
      axes: [...document.querySelectorAll("[data-axis]")].map((c) => ({
        axis: c.dataset.axis,
        applied: c.querySelector(".applied").textContent,
        target: c.querySelector(".target").textContent,
      })),
      channels: [...document.querySelectorAll("#sensors tr[data-channel]")].map((r) => ({
        channel: r.dataset.channel, value: r.children[1].textContent, bad: r.classList.contains("bad"),
      })),
      model: document.querySelector("#model").textContent,
    }));
    await page.waitForTimeout(300);
    out({ event: "shown", shown, status: seen.get(shown.cycles) ?? null });
  }
  // Let the charts collect a few points, then the healthy screenshot.
  await page.waitForFunction(() => document.querySelectorAll(".uplot").length >= 2, null, { timeout: 30000 });
  await page.waitForTimeout(3000);
  await page.screenshot({ path: `${shots}/web-live.png` });
  out({ event: "ready", unix_ms: Date.now() });

  await page.waitForSelector(`tr[data-channel="${channel}"].bad`, { timeout: 120000 });
  const shownMs = Date.now();
  const banner = await page.textContent("#banner");
  out({ event: "fault_shown", unix_ms: shownMs, banner });
  await page.waitForTimeout(2500);
  await page.screenshot({ path: `${shots}/web-fault.png`, fullPage: true });

  // The fault's start is marked on the charts (the next history/fault poll redraws them), and
  // each sensor's age comes from its own reading: the silent one ages, the others stay fresh.
  await page.waitForFunction(() => Number(document.querySelector("#chart-applied").dataset.marks || 0) >= 1, null, { timeout: 30000 });
  out({
    event: "marks_and_ages",
    marks: await page.evaluate(() => [...document.querySelectorAll(".chart")].map((c) => Number(c.dataset.marks || 0))),
    ages: await page.evaluate(() => [...document.querySelectorAll("#sensors tr[data-channel]")].map((r) => ({
      channel: r.dataset.channel, age_s: r.dataset.ageS === "" ? null : Number(r.dataset.ageS), bad: r.classList.contains("bad"),
    }))),
  });

  // A phone (390 × 844): the same page resized, then a fresh page at that size. No horizontal
  // scroll; every chart and legend inside the screen.
  const layout = () => ({
    inner_w: window.innerWidth,
    scroll_w: document.documentElement.scrollWidth,
    charts: [...document.querySelectorAll(".uplot")].map((e) => { const r = e.getBoundingClientRect(); return [r.left, r.right]; }),
    legends: [...document.querySelectorAll(".u-legend")].map((e) => { const r = e.getBoundingClientRect(); return [r.left, r.right]; }),
    // For the failure message: the elements reaching beyond the screen.
    beyond: [...document.querySelectorAll("body *")].filter((e) => e.getBoundingClientRect().right > window.innerWidth + 0.5)
      .slice(0, 8).map((e) => `${e.tagName.toLowerCase()}${e.id ? "#" + e.id : ""}.${e.className} ${Math.round(e.getBoundingClientRect().right)}`),
  });
  await page.setViewportSize({ width: 390, height: 844 });
  // Until the page has re-laid out: no horizontal scroll and the chart and legend boxes inside the
  // screen. The `.uplot` box alone is not enough: CSS narrows it at once, while the chart inside
  // keeps its old width until `resizeCharts` runs (on the resize event or the ResizeObserver, which
  // a busy machine delivers late). On timeout the layout below is recorded as it is, and the test's
  // assertions fail on it.
  const settled = () => document.documentElement.scrollWidth <= window.innerWidth
    && [...document.querySelectorAll(".uplot, .u-legend")].every((e) => e.getBoundingClientRect().right <= window.innerWidth);
  await page.waitForFunction(settled, null, { timeout: 20000 }).catch(() => {});
  out({ event: "narrow", how: "resized", layout: await page.evaluate(layout) });
  await page.screenshot({ path: `${shots}/web-phone.png`, fullPage: true });
  const phone = await browser.newPage({ viewport: { width: 390, height: 844 } });
  await phone.goto(url);
  await phone.waitForFunction(() => document.querySelectorAll(".uplot .u-legend").length >= 2, null, { timeout: 30000 });
  await phone.waitForTimeout(2500);
  out({ event: "narrow", how: "fresh", layout: await phone.evaluate(layout) });
  await phone.close();
  await page.setViewportSize({ width: 1280, height: 1000 });

  await page.fill("#token", "");
  await page.click("#act-disable");
  await page.waitForSelector("#act-result.bad", { timeout: 20000 });
  out({ event: "refused", text: await page.textContent("#act-result") });
  await page.waitForFunction(() => /refused: missing or wrong token/.test(document.querySelector("#action-log").textContent), null, { timeout: 20000 });
  out({ event: "action_logged", text: await page.textContent("#action-log") });
  out({ event: "done", errors });
} finally {
  await browser.close();
}
