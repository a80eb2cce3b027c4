"""Measure an HTML page's layout in headless Chromium at a given width: horizontal scrolling (of the page and of any
element that scrolls sideways), and text boxes that overlap one another (the boxes of every text node, measured
with ``Range.getClientRects``, not a screenshot). Used by the report tests; skipped where Chromium is not installed
(it is a system package, not one of the project's Python dependencies)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or (
    "/usr/bin/chromium" if Path("/usr/bin/chromium").exists() else None)

_PROBE = r"""<script>
window.addEventListener('load', () => {
  const out = {scroll: document.documentElement.scrollWidth - document.documentElement.clientWidth,
               sideways: [], overlaps: []};
  for (const el of document.querySelectorAll('body *')) {
    const style = getComputedStyle(el);
    if (el.scrollWidth > el.clientWidth + 1 && ['auto', 'scroll'].includes(style.overflowX))
      out.sideways.push(el.tagName + (el.id ? '#' + el.id : '') + (el.className ? '.' + el.className : '')
                        + ' ' + el.scrollWidth + '>' + el.clientWidth);
  }
  const boxes = [];
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  while (walker.nextNode()) {
    const node = walker.currentNode;
    if (!node.textContent.trim() || node.parentElement.closest('script,style')) continue;
    const range = document.createRange();
    range.selectNodeContents(node);
    for (const r of range.getClientRects())
      if (r.width > 0 && r.height > 0)
        boxes.push([r.left, r.top, r.right, r.bottom, node.textContent.trim().slice(0, 40)]);
  }
  for (let i = 0; i < boxes.length; i++)
    for (let j = i + 1; j < boxes.length; j++) {
      const a = boxes[i], b = boxes[j];
      const w = Math.min(a[2], b[2]) - Math.max(a[0], b[0]), h = Math.min(a[3], b[3]) - Math.max(a[1], b[1]);
      if (w > 1 && h > 1) out.overlaps.push(a[4] + ' | ' + b[4]);
    }
  const p = document.createElement('pre');
  p.id = 'layout-probe';
  p.textContent = JSON.stringify(out);
  document.body.appendChild(p);
});
</script>"""


def page_layout(html: str, folder: Path, width: int = 1280) -> dict:
    """``{scroll: px of horizontal page scrolling, sideways: elements that scroll sideways, overlaps: pairs of
    overlapping text boxes}`` of ``html`` rendered at ``width`` px (written to ``folder``)."""
    assert CHROMIUM is not None
    path = folder / "layout-probe.html"
    path.write_text(html.replace("<body>", "<body>" + _PROBE, 1), encoding="utf-8")
    done = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                           "--hide-scrollbars", f"--window-size={width},900", "--dump-dom", path.as_uri()],
                          capture_output=True, text=True, timeout=120)
    found = re.search(r'<pre id="layout-probe">(.*?)</pre>', done.stdout, re.S)
    assert found is not None, done.stderr[-2000:]
    return json.loads(found.group(1).replace("&amp;", "&").replace("&lt;", "<").replace("&gt;", ">"))
