// The dashboard's one script (inlined into report.html): a tooltip for every chart mark.
// Each mark (.pt) carries its text in data-tip (for Pareto points: the point's full config).
(function () {
  "use strict";
  const tip = document.getElementById("tip");
  function show(event) {
    const mark = event.currentTarget;
    tip.textContent = mark.getAttribute("data-tip");
    tip.hidden = false;
    mark.classList.add("hover");
    move(event);
  }
  function move(event) {
    const pad = 14;
    let x = event.clientX + pad;
    let y = event.clientY + pad;
    if (x + tip.offsetWidth > window.innerWidth) x = Math.max(0, event.clientX - tip.offsetWidth - pad);
    if (y + tip.offsetHeight > window.innerHeight) y = Math.max(0, event.clientY - tip.offsetHeight - pad);
    tip.style.left = x + "px";
    tip.style.top = y + "px";
  }
  function hide(event) {
    tip.hidden = true;
    event.currentTarget.classList.remove("hover");
  }
  document.querySelectorAll(".pt[data-tip]").forEach(function (mark) {
    mark.addEventListener("mouseenter", show);
    mark.addEventListener("mousemove", move);
    mark.addEventListener("mouseleave", hide);
  });
})();
