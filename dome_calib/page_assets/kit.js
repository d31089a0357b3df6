  // dome_calib/page_assets/kit.js: what every page shares (dome_calib.pages), inlined before the page's own script.
  // 1. A page that fails to build still says why (never a blank page): into the element marked data-page-errors.
  window.addEventListener("error", function (e) {
    var m = document.querySelector("[data-page-errors]");
    if (!m) return;
    m.hidden = false;
    m.appendChild(document.createTextNode("This page could not be built completely: " + e.message));
  });
  // 2. Every string and number from a file reaches the document through these: text (textContent, createTextNode,
  //    the DOM builder el) or, where a page builds markup, esc (text) and num / int_ (numbers; "" for anything else).
  window.PageKit = (function () {
    "use strict";
    const ESC = {"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"};
    const esc = (s) => String(s == null ? "" : s).replace(/[&<>"']/g, (c) => ESC[c]);
    const isNum = (v) => typeof v === "number" && isFinite(v);
    const num = (v, d) => isNum(v) ? esc(v.toFixed(d)) : "";
    const int_ = (v) => isNum(v) ? esc(v.toLocaleString()) : "";
    const own = (o, k) => Object.prototype.hasOwnProperty.call(o, k);
    const $ = (id) => document.getElementById(id);
    function text(node, s) { node.textContent = s == null ? "" : String(s); return node; }
    function el(tag, props, children) {  // an element whose text and attributes are set as data, never parsed
      const node = document.createElement(tag);
      for (const [k, v] of Object.entries(props || {})) {
        if (k === "text") node.textContent = v == null ? "" : String(v);
        else if (k === "className") node.className = String(v);
        else node.setAttribute(k, String(v));
      }
      for (const c of children || []) node.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
      return node;
    }
    return Object.freeze({esc, isNum, num, int_, own, $, text, el});
  })();
