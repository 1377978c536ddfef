// Opens a served Lichtblick in headless Chromium against a live jetbench
// Foxglove view, with the shipped layout as the app's default layout, waits
// for the panels to fill, saves a screenshot, then presses one of the
// layout's buttons (STOP by default) the way a person would: a mouse click on
// the button the Call Service panel draws.
//
//   node lichtblick_check.mjs APP_URL WS_URL SCREENSHOT.png [BUTTON_TEXT] [CHROMIUM]
//
// Prints one JSON line: when the click happened (CLOCK_REALTIME ms), what the
// panel showed after it, and what the page logged as errors.
import puppeteer from "puppeteer-core";

const [appUrl, wsUrl, screenshot, buttonText = "STOP", chromium = "/usr/bin/chromium"] = process.argv.slice(2);
if (!appUrl || !wsUrl || !screenshot) {
  console.error("usage: node lichtblick_check.mjs APP_URL WS_URL SCREENSHOT.png [BUTTON_TEXT] [CHROMIUM]");
  process.exit(2);
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const browser = await puppeteer.launch({
  executablePath: chromium,
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--window-size=1600,1000", "--use-gl=swiftshader"],
  defaultViewport: { width: 1600, height: 1000 },
});
const errors = [];
try {
  const page = await browser.newPage();
  page.on("pageerror", (e) => errors.push(String(e)));
  const url = `${appUrl}?ds=foxglove-websocket&ds.url=${encodeURIComponent(wsUrl)}`;
  await page.goto(url, { waitUntil: "load", timeout: 120_000 });

  // The Call Service panel draws a <button> with the layout's text once the
  // data source says which services exist.
  const findButton = async () => {
    for (const b of await page.$$("button")) {
      try {
        const [text, disabled] = await b.evaluate((el) => [(el.textContent ?? "").trim(), el.disabled]);
        if (text === buttonText && !disabled) {
          return b;
        }
      } catch {
        // Replaced by a re-render while we looked: the next pass finds the new one.
      }
    }
    return undefined;
  };
  let button;
  const deadline = Date.now() + 120_000;
  while (!(button = await findButton())) {
    if (Date.now() > deadline) {
      await page.screenshot({ path: screenshot });
      throw new Error(`no enabled "${buttonText}" button after 120 s (screenshot of what was shown: ${screenshot})`);
    }
    await sleep(500);
  }
  // Let the plots fill with a few seconds of the live run.
  await sleep(8_000);
  await page.screenshot({ path: screenshot });
  // The panels re-render as data comes in: a button found may be replaced
  // before the click lands, so find it again and retry.
  let clickedMs;
  for (let attempt = 0; clickedMs === undefined; attempt++) {
    try {
      button = await findButton();
      if (!button) {
        throw new Error(`the "${buttonText}" button went away`);
      }
      const at = Date.now();
      await button.click();
      clickedMs = at;
    } catch (e) {
      if (attempt >= 10) {
        throw e;
      }
      await sleep(200);
    }
  }
  await sleep(3_000);
  // What the Call Service panels show as the bench's answer.
  const answer = await page.$$eval("textarea", (areas) =>
    areas.map((a) => a.value).filter((v) => v.includes("answer")),
  );
  await page.screenshot({ path: screenshot.replace(/\.png$/, "") + "-after-stop.png" });
  console.log(JSON.stringify({ clicked_ms: clickedMs, answer, errors }));
} finally {
  await browser.close();
}
