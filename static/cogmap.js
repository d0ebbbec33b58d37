// cogmap web app: the page's own behaviour (injected once by app/server/assets.py).
//
// - Text boxes send their content when Enter is pressed or the box loses focus, not on every
//   keystroke: "1e9" is sent as "1e9", never as "1" then "1e" then "1e9".
// - Space plays or pauses (unless a text box or a button has the focus).
// - The tab is titled "cogmap" and shows the cogmap logo.
(function () {
  if (window.__cogmap) return;
  window.__cogmap = true;

  var TITLE = "__COGMAP_TITLE__";
  var ICON = "__COGMAP_ICON__";
  function brand() {
    if (document.title !== TITLE) document.title = TITLE;
    var link = document.querySelector("link[rel~='icon']");
    if (link && link.getAttribute("href") !== ICON) link.setAttribute("href", ICON);
  }
  brand();
  new MutationObserver(brand).observe(document.head, {
    childList: true,
    subtree: true,
    characterData: true,
  });

  // ---- commit text boxes on Enter or blur
  var pending = new Set();
  var releasing = null;
  function isTextBox(el) {
    return (
      el instanceof HTMLInputElement &&
      el.type === "text" &&
      el.classList.contains("mantine-TextInput-input")
    );
  }
  window.addEventListener(
    "input",
    function (event) {
      var el = event.target;
      if (!isTextBox(el) || el === releasing) return;
      event.stopImmediatePropagation(); // React does not see the keystroke (yet)
      pending.add(el);
    },
    true,
  );
  function commit(el) {
    if (!pending.has(el)) return;
    pending.delete(el);
    releasing = el;
    try {
      el.dispatchEvent(new Event("input", { bubbles: true }));
    } finally {
      releasing = null;
    }
  }
  window.addEventListener(
    "keydown",
    function (event) {
      var el = event.target;
      if (event.key === "Enter" && pending.has(el)) {
        event.preventDefault();
        commit(el);
      }
    },
    true,
  );
  window.addEventListener(
    "focusout",
    function (event) {
      commit(event.target);
    },
    true,
  );

  // ---- space: play / pause
  window.addEventListener(
    "keydown",
    function (event) {
      if (event.code !== "Space" || event.repeat || event.ctrlKey || event.metaKey) return;
      var t = event.target;
      if (
        t instanceof HTMLInputElement ||
        t instanceof HTMLTextAreaElement ||
        t instanceof HTMLButtonElement ||
        t instanceof HTMLSelectElement ||
        (t && t.isContentEditable)
      )
        return;
      var buttons = document.querySelectorAll("button");
      for (var i = 0; i < buttons.length; i++) {
        var label = (buttons[i].textContent || "").trim();
        if (label === "play" || label === "pause") {
          event.preventDefault();
          buttons[i].click();
          return;
        }
      }
    },
    true,
  );
})();
