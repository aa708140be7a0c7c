// The members of three.js (web3d/static/node_modules/three, whose package has no types) that controls.js uses:
// its camera and OrbitControls, as three's own documentation declares them.

declare module "three" {
  export class Vector3 {
    x: number;
    y: number;
    z: number;
    set(x: number, y: number, z: number): this;
  }

  export class PerspectiveCamera {
    constructor(fov?: number, aspect?: number, near?: number, far?: number);
    readonly position: Vector3;
    readonly up: Vector3;
    lookAt(target: Vector3): void;
  }
}

declare module "three/addons/controls/OrbitControls.js" {
  import type { PerspectiveCamera, Vector3 } from "three";

  export class OrbitControls {
    constructor(object: PerspectiveCamera, domElement?: HTMLElement | null);
    enabled: boolean;
    readonly target: Vector3;
    keyPanSpeed: number;
    keyRotateSpeed: number;
    listenToKeyEvents(domElement: HTMLElement): void;
    dollyIn(dollyScale: number): void;
    dollyOut(dollyScale: number): void;
  }
}
