// An interactive 3D view of a robot from its URDF, posed where the simulator starts it
// when the server says where that is (GET /api/v1/trials/{id}/spawn: the root frame's
// pose, the joints' positions), else in the URDF's own frame with its joints at zero:
// drag to orbit, scroll to zoom, right-drag to pan, one slider per movable joint. three and urdf-loader come from one
// vendored ES module (../vendor/three-urdf.js, see vendor/README.md), loaded the first
// time a view shows a robot. It draws primitive shapes (box, cylinder, sphere) and fetches
// nothing but the URDF: the mesh files a URDF names are left out (the view says how many),
// and its textures (colours stay). It renders on demand (a move, a slider, a resize).
// Given the trial's replay (replay.json, adclient.schemas.Replay: the root frame's pose and
// the joints per recorded control step), it plays the evaluation episode in the
// simulator's own pose: play, pause, a scrubber and a speed.

import { getJSON, getText } from './api.js';
import { formatNumber } from './charts.js';
import { element, esc, finder } from './html.js';

const BACKGROUND = 0xf9fafb;
const UNITS = { revolute: 'rad', continuous: 'rad', prismatic: 'm' };
const SPEEDS = [0.25, 0.5, 1, 2, 4];
const BASE_SIZE = 7; // a replay frame's root position (3) and quaternion x, y, z, w (4)

let vendor = null;

function loadVendor() {
  vendor ??= import('../vendor/three-urdf.js');
  return vendor;
}

/** A joint's slider range, or null for a joint that cannot move along one axis. */
function sliderRange(joint) {
  if (joint.jointType === 'continuous') return [-Math.PI, Math.PI];
  if (joint.jointType !== 'revolute' && joint.jointType !== 'prismatic') return null;
  const { lower, upper } = joint.limit;
  return upper > lower ? [lower, upper] : null;
}

function disposeObject(object) {
  object.traverse((part) => {
    part.geometry?.dispose();
    for (const material of [part.material ?? []].flat()) material.dispose();
  });
}

export class RobotView {
  constructor() {
    this.root = element(`<div class="robot-view">
      <div class="robot-stage">
        <canvas data-robot-canvas
          aria-label="The robot in 3D: drag to turn it, scroll to zoom, right-drag to move"></canvas>
        <button type="button" class="robot-reset" data-robot-reset
          title="Joints back to where they start, camera back to the whole robot">Reset</button>
      </div>
      <div class="replay" data-replay hidden>
        <button type="button" data-replay-play aria-label="Play the evaluation episode">Play</button>
        <input type="range" data-replay-scrub min="0" max="0" step="1" value="0"
          aria-label="Time in the evaluation episode">
        <output data-replay-time></output>
        <select data-replay-speed aria-label="Playback speed">
          ${SPEEDS.map((speed) => `<option value="${speed}"${speed === 1 ? ' selected' : ''}>${speed}×</option>`).join('')}
        </select>
      </div>
      <p class="meta" data-robot-note hidden></p>
      <div class="joints" data-sliders></div>
    </div>`);
    const $ = finder(this.root);
    this.canvas = $('robot-canvas');
    this.sliders = $('sliders');
    this.noteText = $('robot-note');
    this.url = null;
    this.requests = 0;
    this.robot = null;
    this.sliders.addEventListener('input', (event) => this.moveJoint(event.target));
    $('robot-reset').addEventListener('click', () => this.reset());
    this.player = $('replay');
    this.playButton = $('replay-play');
    this.scrubber = $('replay-scrub');
    this.timeText = $('replay-time');
    this.speed = $('replay-speed');
    this.replay = null;
    this.frame = 0;
    this.playing = null; // the animation frame request while playing
    this.playButton.addEventListener('click', () => (this.playing ? this.pause() : this.play()));
    this.scrubber.addEventListener('input', () => {
      this.pause();
      this.showFrame(Number(this.scrubber.value));
    });
    this.speed.addEventListener('change', () => {
      if (!this.playing) return;
      this.pause(); // on from this frame at the new speed
      this.play();
    });
  }

  /** Play `replay` (replay.json) here: the player shows, at its first frame. */
  setReplay(replay) {
    if (!this.robot || !replay?.frames?.length) return;
    this.replay = replay;
    this.period = replay.control_period * (replay.every ?? 1);
    this.scrubber.max = String(replay.frames.length - 1);
    this.player.hidden = false;
    this.canvas.dataset.replayFrames = String(replay.frames.length);
    this.showFrame(0);
  }

  /** The robot as the simulator had it at frame `k` of the replay. */
  showFrame(k) {
    const replay = this.replay;
    const frame = replay.frames[k];
    this.frame = k;
    this.robot.position.set(frame[0], frame[1], frame[2]).applyQuaternion(this.upright);
    this.robot.quaternion.set(frame[3], frame[4], frame[5], frame[6]).premultiply(this.upright);
    replay.joints.forEach((name, j) => {
      const value = frame[BASE_SIZE + j];
      const input = [...this.sliders.querySelectorAll('input[data-joint]')].find(
        (slider) => slider.dataset.joint === name,
      );
      if (input) {
        input.value = String(value);
        this.setJoint(input);
      } else {
        this.robot.setJointValue(name, value);
      }
    });
    this.scrubber.value = String(k);
    const seconds = k * this.period;
    const total = (replay.frames.length - 1) * this.period;
    this.timeText.textContent = `${seconds.toFixed(2)} / ${total.toFixed(2)} s`;
    this.canvas.dataset.frame = String(k);
    this.canvas.dataset.base = JSON.stringify(this.basePose());
    this.render();
  }

  /** From the scrubber's frame (the start, when at the end) at the chosen speed, in
   * simulated time; stops at the episode's last frame. */
  play() {
    if (!this.replay || this.playing) return;
    const last = this.replay.frames.length - 1;
    const from = this.frame >= last ? 0 : this.frame;
    let started = null;
    const tick = (now) => {
      started ??= now - from * this.period * 1000 / Number(this.speed.value);
      const seconds = ((now - started) / 1000) * Number(this.speed.value);
      const k = Math.min(last, Math.floor(seconds / this.period));
      if (k !== this.frame) this.showFrame(k);
      if (k >= last) {
        this.pause();
        return;
      }
      this.playing = requestAnimationFrame(tick);
    };
    this.playing = requestAnimationFrame(tick);
    this.playButton.textContent = 'Pause';
    this.player.dataset.playing = 'true';
  }

  pause() {
    if (this.playing) cancelAnimationFrame(this.playing);
    this.playing = null;
    this.playButton.textContent = 'Play';
    this.player.dataset.playing = 'false';
  }

  /** Show the robot whose URDF is at `url`, where the spawn pose at `spawnUrl` puts it
   * (none: in its URDF frame); a later call wins over one still loading. */
  async show(url, spawnUrl = null) {
    if (url === this.url) return;
    this.url = url;
    const request = ++this.requests;
    this.root.dataset.url = url;
    delete this.canvas.dataset.ready;
    try {
      const [three, urdf, spawn] = await Promise.all([
        loadVendor(),
        getText(url),
        spawnUrl ? getJSON(spawnUrl).catch((error) => ({ error })) : null,
      ]);
      if (request !== this.requests) return;
      this.setUp(three);
      this.setRobot(urdf, spawn);
    } catch (error) {
      if (request !== this.requests) return;
      this.url = null;
      this.note(`No 3D view: ${error.message}`);
    }
  }

  setUp(three) {
    if (this.renderer) return;
    this.three = three;
    this.renderer = new three.WebGLRenderer({
      canvas: this.canvas,
      antialias: true,
      preserveDrawingBuffer: true, // what is drawn stays readable: "save image", tests
    });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    this.renderer.setClearColor(BACKGROUND);
    this.scene = new three.Scene();
    this.scene.add(new three.AmbientLight(0xffffff, 1.6));
    this.camera = new three.PerspectiveCamera(40, 1, 0.01, 100);
    const headlight = new three.DirectionalLight(0xffffff, 2.2);
    headlight.position.set(0.5, 1, 0.5);
    this.camera.add(headlight);
    this.scene.add(this.camera);
    this.controls = new three.OrbitControls(this.camera, this.canvas);
    this.controls.addEventListener('change', () => this.render());
    this.resizer = new ResizeObserver(() => this.resize());
    this.resizer.observe(this.canvas);
  }

  /** Draw the URDF's robot at `spawn` ({position, orientation, joints}; null: in its
   * URDF frame; {error}: the same, saying why). */
  setRobot(urdf, found) {
    const spawn = found?.error ? null : found;
    const three = this.three;
    const xml = new DOMParser().parseFromString(urdf, 'text/xml');
    if (xml.documentElement.nodeName !== 'robot') throw new Error('not a URDF (no <robot> element)');
    if (this.robot) {
      this.scene.remove(this.robot);
      disposeObject(this.robot);
    }
    const manager = new three.LoadingManager();
    manager.setURLModifier(() => 'data:,'); // a texture file a URDF names: not fetched
    const loader = new three.URDFLoader(manager);
    const meshes = [];
    loader.loadMeshCb = (path, _manager, _material, done) => {
      meshes.push(path);
      done(null);
    };
    this.robot = loader.parse(xml);
    this.robot.traverse((part) => {
      if (part.material?.map) part.material.map = null; // its file was not fetched: colour only
    });
    // URDF and the simulator are z-up, three is y-up: the z-up world turned onto three's.
    const xAxis = new three.Vector3(1, 0, 0);
    this.upright = this.robot.quaternion.clone().setFromAxisAngle(xAxis, -Math.PI / 2);
    this.robot.position.set(...(spawn?.position ?? [0, 0, 0])).applyQuaternion(this.upright);
    this.robot.quaternion.set(...(spawn?.orientation ?? [0, 0, 0, 1])).premultiply(this.upright);
    this.start = spawn?.joints ?? {};
    this.home = [this.robot.position.clone(), this.robot.quaternion.clone()];
    this.scene.add(this.robot);

    const movable = Object.values(this.robot.joints)
      .map((joint) => [joint, sliderRange(joint)])
      .filter(([, range]) => range);
    this.sliders.innerHTML = movable
      .map(([joint, [low, high]]) => {
        const unit = UNITS[joint.jointType];
        return `<label class="joint"><span title="${esc(joint.name)} (${esc(joint.jointType)})">${esc(joint.name)}</span>
          <input type="range" data-joint="${esc(joint.name)}" data-unit="${unit}" min="${low}" max="${high}"
            step="any">
          <output></output></label>`;
      })
      .join('');
    this.canvas.dataset.links = String(Object.keys(this.robot.links).length);
    this.canvas.dataset.joints = String(movable.length);
    this.startJoints();
    this.canvas.dataset.spawn = spawn ? 'true' : 'false';
    this.canvas.dataset.base = JSON.stringify(this.basePose());
    this.resize();
    const shapes = this.fit();
    const notes = [];
    if (found?.error) notes.push(`Drawn in its URDF frame: no spawn pose (${found.error.message}).`);
    if (meshes.length) {
      notes.push(`${meshes.length} mesh file(s) not drawn: this view draws boxes, cylinders and spheres.`);
    }
    if (!shapes) notes.push('This URDF has no shapes to draw.');
    this.note(notes.join(' '));
    this.render();
    this.canvas.dataset.ready = 'true';
  }

  /** Every joint where the simulator starts it, or, not told, at zero or the limit
   * nearest zero (where the simulator starts a joint too). */
  startJoints() {
    for (const input of this.sliders.querySelectorAll('input[data-joint]')) {
      const start = this.start[input.dataset.joint] ?? 0;
      input.value = String(Math.min(Number(input.max), Math.max(Number(input.min), start)));
      this.setJoint(input);
    }
  }

  /** The root frame's pose as drawn, in the z-up world the URDF and the simulator use:
   * {position, orientation (x, y, z, w)}. */
  basePose() {
    const back = this.upright.clone().invert();
    return {
      position: this.robot.position.clone().applyQuaternion(back).toArray(),
      orientation: this.robot.quaternion.clone().premultiply(back).toArray(),
    };
  }

  setJoint(input) {
    const value = Number(input.value);
    this.robot.setJointValue(input.dataset.joint, value);
    // Shown to a millimetre or a milliradian.
    input.nextElementSibling.textContent = `${formatNumber(Number(value.toFixed(3)))} ${input.dataset.unit}`;
  }

  moveJoint(input) {
    if (!input.matches('input[data-joint]') || !this.robot) return;
    this.setJoint(input);
    this.render();
  }

  /** The camera on the whole robot, a grid under it; false when it has nothing to draw. */
  fit() {
    const { Box3, GridHelper, Vector3 } = this.three;
    if (this.grid) {
      this.scene.remove(this.grid);
      this.grid.dispose();
    }
    this.robot.updateMatrixWorld(true);
    const box = new Box3().setFromObject(this.robot);
    const empty = box.isEmpty();
    const center = empty ? new Vector3() : box.getCenter(new Vector3());
    const extent = box.getSize(new Vector3());
    const radius = empty ? 0.5 : Math.max(extent.length() / 2, 0.05);
    // How far the robot fitted reaches along the z-up world's x, y and z (three's x, z, y).
    this.canvas.dataset.extent = JSON.stringify(empty ? [0, 0, 0] : [extent.x, extent.z, extent.y]);
    const halfFov = (this.camera.fov * Math.PI) / 360;
    const halfWidth = Math.atan(Math.tan(halfFov) * this.camera.aspect);
    const distance = (radius / Math.sin(Math.min(halfFov, halfWidth))) * 1.2;
    const direction = new Vector3(1, 0.7, 1.4).normalize();
    this.camera.position.copy(center).addScaledVector(direction, distance);
    this.camera.near = distance / 100;
    this.camera.far = distance * 100;
    this.camera.updateProjectionMatrix();
    this.controls.target.copy(center);
    this.controls.update();
    const size = Math.max(1, Math.ceil(radius * 4));
    this.grid = new GridHelper(size, size * 4, 0x9ca3af, 0xd1d5db);
    this.grid.position.set(center.x, empty ? 0 : box.min.y, center.z);
    this.scene.add(this.grid);
    return !empty;
  }

  reset() {
    if (!this.robot) return;
    this.pause();
    this.robot.position.copy(this.home[0]);
    this.robot.quaternion.copy(this.home[1]);
    this.startJoints();
    this.canvas.dataset.base = JSON.stringify(this.basePose());
    this.fit();
    this.render();
  }

  resize() {
    const width = this.canvas.clientWidth;
    const height = this.canvas.clientHeight;
    if (!this.renderer || !width || !height) return;
    this.renderer.setSize(width, height, false);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    if (!this.robot) return;
    this.renderer.render(this.scene, this.camera);
  }

  note(text) {
    this.noteText.textContent = text;
    this.noteText.hidden = !text;
  }

  /** Let go of the GPU context and the listeners; the view is not used again. */
  dispose() {
    this.requests += 1;
    this.pause();
    this.resizer?.disconnect();
    this.controls?.dispose();
    if (this.robot) disposeObject(this.robot);
    this.grid?.dispose();
    this.renderer?.dispose();
    this.renderer?.forceContextLoss();
  }
}
