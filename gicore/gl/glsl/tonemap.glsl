// gicore.tonemap: Reinhard, then display gamma 2.2, and its inverse (display values clipped just below 1).
vec3 tonemap(vec3 x) { x = max(x, 0.0); return pow(x / (1.0 + x), vec3(1.0 / 2.2)); }
vec3 inverse_tonemap(vec3 y) { y = pow(clamp(y, 0.0, 1.0 - 1e-5), vec3(2.2)); return y / (1.0 - y); }
