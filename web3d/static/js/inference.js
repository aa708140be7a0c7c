// onnxruntime-web's session for GIGAN's generator, run off the page's thread in onnxruntime-web's proxy worker
// (env.wasm.proxy: session.run posts the input there and resolves when the output comes back, so the frame loop
// keeps drawing meanwhile). The WebGPU build when the browser has an adapter (and --backend allows it), else the
// wasm-only build (half the wasm to compile).

/**
 * @param {{backend: string, threads: number}} config
 * @param {Record<string, unknown>} info where it says which backend it runs and how
 * @returns {Promise<{ort: typeof import("onnxruntime-web"), session: import("onnxruntime-web").InferenceSession}>}
 */
export async function openSession(config, info) {
  const adapter = config.backend !== "wasm" && "gpu" in navigator && (await navigator.gpu.requestAdapter().catch(() => null));
  if (config.backend === "webgpu" && !adapter) throw new Error("--backend webgpu: this browser has no WebGPU adapter");
  const ort = await import(adapter ? "/npm/onnxruntime-web/ort.all.min.mjs" : "/npm/onnxruntime-web/ort.wasm.min.mjs");
  ort.env.wasm.wasmPaths = "/npm/onnxruntime-web/";
  ort.env.wasm.numThreads = crossOriginIsolated ? config.threads : 1;
  ort.env.wasm.proxy = true;
  const model = await (await fetch("/assets/model/model.onnx")).arrayBuffer();
  const providers = adapter ? ["webgpu", "wasm"] : ["wasm"];
  // GIModel's settings: all graph optimisations, intra-op threads that do not spin after a run (they would hold
  // the cores the WebGL passes need)
  const options = { executionProviders: providers, graphOptimizationLevel: "all",
    extra: { session: { intra_op: { allow_spinning: "0" } } } };
  const session = await ort.InferenceSession.create(model, options);
  Object.assign(info, { backend: adapter ? "webgpu" : "wasm", wasm_threads: ort.env.wasm.numThreads, proxy: true });
  return { ort, session };
}
