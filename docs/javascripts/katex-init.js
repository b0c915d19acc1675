// Typesets the maths pymdownx.arithmatex leaves in the page (\( ... \) inline, \[ ... \] displayed) with the
// KaTeX copy served from the site itself (docs/javascripts/katex/, no CDN), once the page has loaded.
document.addEventListener("DOMContentLoaded", function () {
  document.querySelectorAll(".arithmatex").forEach(function (element) {
    var tex = element.textContent.trim();
    var display = tex.startsWith("\\[");
    katex.render(tex.slice(2, -2), element, { displayMode: display, throwOnError: false });
  });
});
