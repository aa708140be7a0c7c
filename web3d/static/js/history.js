// A bounded history: the last `capacity` records pushed, each known by its index since the first (0, 1, ...), so
// that a reader outside the page (bench web, the tests) can take what is new since it last read without the page
// keeping every record for it. The oldest are dropped past the capacity; asking for a dropped one is an error.

/** @template T */
export class History {
  /** @type {(T | undefined)[]} */
  #ring;
  #count = 0;

  /**
   * @param {string} name what the records are, for the error that asks for dropped ones
   * @param {number} capacity records kept
   */
  constructor(name, capacity) {
    if (!(Number.isInteger(capacity) && capacity > 0)) throw new Error(`${name}: keep at least one record`);
    this.name = name;
    this.capacity = capacity;
    this.#ring = new Array(capacity);
  }

  /** Records pushed since the page loaded (the next one's index). */
  get count() {
    return this.#count;
  }

  /** The index of the oldest record kept. */
  get first() {
    return Math.max(0, this.#count - this.capacity);
  }

  /** @param {T} record */
  push(record) {
    this.#ring[this.#count % this.capacity] = record;
    this.#count++;
  }

  /**
   * The records from index `start` on, oldest first; an error when some of them were dropped.
   * @param {number} start
   * @returns {T[]}
   */
  since(start) {
    if (start < this.first) {
      throw new Error(`${this.name} ${start} to ${this.first - 1} are no longer kept (the page keeps the last ` +
        `${this.capacity}): read them more often`);
    }
    const out = [];
    for (let i = start; i < this.#count; i++) out.push(/** @type {T} */ (this.#ring[i % this.capacity]));
    return out;
  }

  /**
   * The last `n` records (fewer when fewer are kept), oldest first.
   * @param {number} n
   */
  recent(n) {
    return this.since(Math.max(this.first, this.#count - n));
  }

  /** The newest record, or undefined before the first. */
  last() {
    return this.#count ? this.#ring[(this.#count - 1) % this.capacity] : undefined;
  }
}
