import { api, saveSession, session } from "./api.js";
import { $ } from "./ui.js";

const params = new URLSearchParams(location.search);
const next = params.get("next") && params.get("next").startsWith("/") ? params.get("next") : "/experiments";
if (session()) $("#login-error").textContent = "";

$("#login-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const username = $("#username").value.trim();
  const password = $("#password").value;
  const out = $("#login-error");
  if (!username || !password) {
    out.textContent = "Enter your username and your password.";
    return;
  }
  out.textContent = "";
  try {
    const answer = await api("POST", "/api/auth/login", { body: { username, password }, noAuthRedirect: true });
    saveSession(answer.token, answer.user, $("#remember").checked);
    location.href = next;
  } catch (err) {
    out.textContent = err.status === 401 ? `Login refused: ${err.message}` : err.message;
  }
});
