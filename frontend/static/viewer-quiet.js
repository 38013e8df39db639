// Loaded into the 3D view (viser's page, served by app/viewer/relay.py). Panel PCs have no GPU, so
// viser shows "Software WebGL rendering detected" over the view and never closes it by itself; the
// view is fast enough that way. Close that one notice, and leave every other notice alone.
"use strict";
new MutationObserver(() => {
  for (const n of document.querySelectorAll(".mantine-Notification-root")) {
    if (!/Software WebGL rendering/.test(n.textContent)) continue;
    const close = n.querySelector(".mantine-Notification-closeButton");
    if (close) close.click(); else n.remove();
  }
}).observe(document.documentElement, { childList: true, subtree: true });
