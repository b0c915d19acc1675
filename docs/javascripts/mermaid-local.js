// The site's own copy of mermaid (javascripts/mermaid/, MIT), loaded only on a page with a diagram: the theme
// uses a global `mermaid` when there is one, and would otherwise fetch it from a CDN, which an offline reader
// (or CI) cannot reach. Written into the page while it is parsed, so that it runs before the theme draws.
(function () {
  if (document.querySelector(".mermaid")) {
    var source = new URL("mermaid/mermaid.min.js", document.currentScript.src).href;
    document.write('<script src="' + source + '"><\/script>');
  }
})();
