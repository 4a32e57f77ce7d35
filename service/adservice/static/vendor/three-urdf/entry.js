// What the dashboard's 3D robot view (js/robot-view.js) uses of three and urdf-loader,
// bundled into one same-origin ES module, ../three-urdf.js, by `npm ci && npm run build`.
export {
  AmbientLight,
  Box3,
  DirectionalLight,
  GridHelper,
  LoadingManager,
  PerspectiveCamera,
  Scene,
  Vector3,
  WebGLRenderer,
} from 'three';
export { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
export { default as URDFLoader } from 'urdf-loader';
