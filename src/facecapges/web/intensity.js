// The gesture intensity slider of the viewer (viewer.html, our avatar or a VRM): an <input type=range id=intensity>
// 0 … 1.3 and a <span id=intensity-value>. Moving it sends {"type": "intensity", "value": v} over the feed's
// WebSocket (facecapges/runtime/outputs/protocol.py); the server's `hello` and `intensity` messages set it, so every
// open viewer shows the value that is applied.
const $ = (id) => document.getElementById(id);

export function intensitySlider() {
  const input = $('intensity');
  const label = $('intensity-value');
  let socket = null;
  const show = (v) => { input.value = String(v); label.textContent = Number(v).toFixed(2); };
  input.addEventListener('input', () => {
    label.textContent = Number(input.value).toFixed(2);
    if (socket && socket.readyState === WebSocket.OPEN) {
      socket.send(JSON.stringify({ type: 'intensity', value: Number(input.value) }));
    }
  });
  return {
    attach(ws) { socket = ws; },
    // true when the message was the slider's (hello's value is read, the message still goes on)
    handle(msg) {
      if (msg.type === 'hello' && msg.intensity !== undefined) show(msg.intensity);
      if (msg.type === 'intensity') { show(msg.value); return true; }
      return false;
    },
  };
}
