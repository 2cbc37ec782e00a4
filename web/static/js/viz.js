// The 3D card: runs a preview job (with progress) or asks for a replay, then embeds viser.
import { api } from "./api.js";
import { $, el, fmt } from "./ui.js";

let generation = 0; // a newer request supersedes an older one still polling
let shownTrialId = null; // the trial the 3D card shows (null: closed)

/** Close the 3D card unless it shows `trialId`: never a previous trial's preview next to
 * another trial's safety gate. */
export function closeUnlessFor(trialId) {
  if (shownTrialId !== null && shownTrialId !== trialId) closeCard();
}

function closeCard() {
  generation++;
  shownTrialId = null;
  $("#viz-card").hidden = true;
  $("#viz-frame-holder").replaceChildren();
}

function card() {
  const c = $("#viz-card");
  c.hidden = false;
  $("#viz-close").onclick = closeCard;
  return c;
}

function progress(fraction, label) {
  const p = $("#viz-progress");
  p.hidden = fraction === null;
  if (fraction !== null) {
    p.querySelector(".bar").style.width = `${Math.round(Math.max(0, Math.min(1, fraction)) * 100)}%`;
    p.querySelector(".label").textContent = label;
  }
}

/** The view through the main port (proxied to viser): one forwarded port is enough. */
function viserUrl(view) {
  const ws = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${view.proxy_websocket_path}`;
  return `${location.origin}${view.proxy_url}?websocket=${encodeURIComponent(ws)}&hideViserLogo`;
}

async function embed(body, legend, gen) {
  progress(0.95, "drawing the arm in 3D…");
  const view = await api("POST", "/viz/views", { body });
  if (gen !== generation) return;
  progress(null);
  $("#viz-legend").textContent = [legend || `Showing ${view.label}.`, view.overlay_label ? `Blue, see-through: the best trial so far, ${view.overlay_label}.` : ""].filter(Boolean).join(" ");
  $("#viz-frame-holder").replaceChildren(el("iframe", {
    id: "viz-frame", src: viserUrl(view), title: `3D view: ${view.label}`, allow: "fullscreen",
  }));
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

/** Preview: a sim rollout of exactly this trial's schedule, run by the server's preview jobs. */
export async function openPreview(trial, incumbentId) {
  const gen = ++generation;
  card();
  shownTrialId = trial.id;
  $("#viz-title").textContent = `preview of trial ${trial.index}`;
  $("#viz-error").textContent = "";
  $("#viz-legend").textContent = "";
  $("#viz-frame-holder").replaceChildren();
  progress(0.02, "asking the server for a preview…");
  ($("#next-card") || card()).scrollIntoView({ block: "start" });
  try {
    const { job_id: jobId } = await api("POST", `/api/trials/${trial.id}/preview`);
    let job;
    for (;;) {
      if (gen !== generation) return;
      job = await api("GET", `/api/previews/${jobId}`);
      // PreviewJobRead.status: queued | running | done | error
      if (job.status === "error") throw new Error(`the preview failed: ${job.error || "no reason given"}`);
      if (job.status === "done") break;
      progress(0.05 + 0.85 * job.progress, `${job.status}: simulating 5 s of motion… ${Math.round(job.progress * 100)}%`);
      await sleep(400);
    }
    const hits = job.bend_limit_hits || [];
    const words = [
      `Sim preview of trial ${trial.index}: predicted max tip speed ${fmt(job.predicted_tip_speed)} m/s.`,
      hits.length ? `WARNING: joint${hits.length > 1 ? "s" : ""} ${hits.join(", ")} would reach the bend limit.` : "No joint reaches its bend limit.",
    ];
    $("#next-preview-summary")?.replaceChildren(words.join(" "));
    const state = document.getElementById("preview-state");
    if (state) state.textContent = `Previewed by you just now (schedule ${String(job.schedule_hash).slice(0, 12)}…): you may confirm it.`;
    await embed({ trial_id: trial.id, preview_job_id: jobId, overlay_trial_id: incumbentId ?? null }, words.join(" "), gen);
  } catch (err) {
    if (gen !== generation) return;
    progress(null);
    $("#viz-error").textContent = `Preview not shown: ${err.message}`;
  }
}

/** Replay a trial (its recorded motion, or a sim of what it ran), optionally with an overlay. */
export async function openReplay(trial, overlayId) {
  const gen = ++generation;
  card();
  shownTrialId = trial.id;
  $("#viz-title").textContent = `trial ${trial.index}`;
  $("#viz-error").textContent = "";
  $("#viz-frame-holder").replaceChildren();
  progress(0.3, "preparing the replay…");
  try {
    const overlay = overlayId && overlayId !== trial.id ? overlayId : null;
    await embed({ trial_id: trial.id, overlay_trial_id: overlay }, "", gen);
  } catch (err) {
    if (gen !== generation) return;
    progress(null);
    $("#viz-error").textContent = `Replay not shown: ${err.message}`;
  }
  card().scrollIntoView({ block: "start" });
}
