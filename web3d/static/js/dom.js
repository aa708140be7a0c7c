// The page's elements (index.html), found by id and checked to be what the modules take them for.

/**
 * @template {HTMLElement} E
 * @param {string} id
 * @param {{new (): E, name: string}} type
 * @returns {E}
 */
export function byId(id, type) {
  const el = document.getElementById(id);
  if (!(el instanceof type)) throw new Error(`index.html has no ${type.name} with id ${id}`);
  return el;
}
