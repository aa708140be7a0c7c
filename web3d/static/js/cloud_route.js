// Where the cloud pane's requests go: gigan-web's /v1/gimap through a network profile's proxy to a store's server,
// each chosen in the page's selects or through viewer.setProfile and viewer.setStore. A change asks for a map at
// once (`onChange`).

/** @typedef {"profile" | "store"} Kind */

export class CloudRoute {
  /**
   * @param {{profiles: string[], profile: string | null, stores: string[], store: string | null}} config
   * @param {Record<Kind, HTMLSelectElement>} selects
   * @param {() => void} onChange
   */
  constructor(config, selects, onChange) {
    this.names = { profile: config.profiles, store: config.stores };
    this.selects = selects;
    this.onChange = onChange;
    const first = (/** @type {string | null} */ name, /** @type {string[]} */ names) =>
      name !== null && names.includes(name) ? name : names[0];
    this.profile = first(config.profile, config.profiles);
    this.store = first(config.store, config.stores);
    for (const kind of /** @type {Kind[]} */ (["profile", "store"])) {
      const select = selects[kind];
      select.replaceChildren(...this.names[kind].map((name) => new Option(name)));
      select.value = this[kind];
      select.addEventListener("change", () => this.set(kind, select.value));
    }
  }

  /**
   * Route the next requests through profile or store `name`.
   * @param {Kind} kind
   * @param {string} name
   */
  set(kind, name) {
    const names = this.names[kind];
    const call = kind === "profile" ? "setProfile" : "setStore";
    if (!names.includes(name)) throw new Error(`${call}: ${name} is not one of ${names.join(", ")}`);
    this[kind] = name;
    this.selects[kind].value = name;
    this.onChange();
  }

  /** The request URL: /v1/gimap?profile=&store=. */
  url() {
    return `/v1/gimap?profile=${encodeURIComponent(this.profile)}&store=${encodeURIComponent(this.store)}`;
  }
}
