// The page's life: loading, then ready (the frame loop runs), an autoplay done, or stopped by an error, which the
// status line shows and viewer.error holds.

export class Lifecycle {
  /** @param {HTMLElement} status the status line */
  constructor(status) {
    this.status = status;
    this.ready = false;
    this.done = false;
    /** @type {string | null} */
    this.error = null;
  }

  /**
   * Stop the page on `e`: the frame loop draws no more.
   * @param {unknown} e
   */
  fail(e) {
    this.error = String(e instanceof Error && e.stack ? e.stack : e);
    this.done = true;
    this.status.textContent = `error: ${e}`;
    console.error(e);
  }
}
