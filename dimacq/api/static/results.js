// What the page and the report show of a solution result.

/** The ten parameters (inertia about the reference point P, as solved) with their 95 %
 * intervals (result.uncertainty), then the principal moments about the CG (with theirs when
 * the result has them: uncertainty.principal_moments). */
export function paramRows(r) {
  const u = r.uncertainty || {};
  const rows = [["mass", "kg", r.mass_kg, u.m]];
  "xyz".split("").forEach((ax, k) => rows.push([`CG ${ax}`, "m", r.cg_m[k], u[`c${ax}`]]));
  const I = r.inertia_p_kgm2;
  const names = [["Ixx", 0, 0], ["Iyy", 1, 1], ["Izz", 2, 2], ["Ixy", 0, 1], ["Ixz", 0, 2], ["Iyz", 1, 2]];
  for (const [n, a, b] of names) rows.push([`${n} (about P)`, "kg m²", I[a][b], u[n]]);
  (r.principal_moments_kgm2 || []).forEach((v, k) => rows.push([`I${k + 1} principal (CG)`, "kg m²", v, (u.principal_moments || [])[k]]));
  return rows;
}
