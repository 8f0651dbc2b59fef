// Render the maths that pymdownx.arithmatex (generic mode) leaves as \( \) and \[ \] inside
// span/div.arithmatex, with the KaTeX files vendored next to this script (no CDN).
function renderMaths(root) {
  for (const el of root.querySelectorAll(".arithmatex")) {
    if (el.dataset.rendered) continue;
    const tex = el.textContent.trim();
    const display = tex.startsWith("\\[");
    const body = tex.replace(/^\\[\[(]/, "").replace(/\\[\])]$/, "");
    katex.render(body, el, { displayMode: display, throwOnError: false });
    el.dataset.rendered = "1";
  }
}

if (typeof document$ !== "undefined") {
  document$.subscribe(({ body }) => renderMaths(body));
} else {
  document.addEventListener("DOMContentLoaded", () => renderMaths(document.body));
}
