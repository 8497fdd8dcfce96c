/* Issue 39's MCML side by side (scripts/mcml_side_by_side.py): a driver for MCML 1.2's own transport, its
 * mcmlgo.c compiled unchanged beside this file (MCML's source is not in this repository; see the script's
 * docstring). One layer between ambient media of n = 1; the photon loop of MCML's DoOneRun (mcmlmain.c);
 * the layer's critical angles as MCML's input reader sets them; Rd and Tt as MCML sums them (Rd_ra, Tt_ra
 * over the launched photons). No input parser and no output file: the transport alone is timed.
 *   usage: mcml_seed PHOTONS MUA_PER_CM MUS_PER_CM G N THICKNESS_CM   (prints one JSON line) */
#include "mcml.h"

double Rspecular(LayerStruct*);
void LaunchPhoton(double, LayerStruct*, PhotonStruct*);
void HopDropSpin(InputStruct*, PhotonStruct*, OutStruct*);

static double** matrix(int rows, int cols) {
    double** m = malloc(sizeof(double*) * rows);
    for (int i = 0; i < rows; ++i) m[i] = calloc(cols, sizeof(double));
    return m;
}

static double cos_crit(double n1, double n2) { return n1 > n2 ? sqrt(1.0 - n2 * n2 / (n1 * n1)) : 0.0; }

int main(int argc, char* argv[]) {
    if (argc != 7) {
        fprintf(stderr, "usage: %s PHOTONS MUA MUS G N THICKNESS_CM\n", argv[0]);
        return 2;
    }
    // Each argument's range (MCML's loop counts down to zero after each photon: a count below 1 would run
    // almost forever).
    const char* names[7] = {0, "PHOTONS", "MUA", "MUS", "G", "N", "THICKNESS_CM"};
    const double lo[7] = {0, 1, 0, 0, -1, 1, 0}, hi[7] = {0, 9e18, 1e9, 1e9, 1, 10, 1e9};
    const int open_lo[7] = {0, 0, 0, 0, 1, 0, 1}, open_hi[7] = {0, 0, 0, 0, 1, 0, 0};
    double v[7];
    for (int k = 1; k < 7; ++k) {
        char* end;
        v[k] = strtod(argv[k], &end);
        const int below = open_lo[k] ? !(v[k] > lo[k]) : !(v[k] >= lo[k]);
        const int above = open_hi[k] ? !(v[k] < hi[k]) : !(v[k] <= hi[k]);
        if (*end != '\0' || end == argv[k] || below || above) {
            fprintf(stderr, "%s = %s: need a number in %c%g, %g%c\n", names[k], argv[k], open_lo[k] ? '(' : '[', lo[k],
                    hi[k], open_hi[k] ? ')' : ']');
            return 2;
        }
    }
    if (v[2] + v[3] <= 0) {
        fprintf(stderr, "MUA + MUS = %g: need a turbid layer (> 0)\n", v[2] + v[3]);
        return 2;
    }
    LayerStruct layers[3] = {{0}};
    layers[0].n = 1.0;
    layers[2].n = 1.0;
    layers[1].mua = v[2];
    layers[1].mus = v[3];
    layers[1].g = v[4];
    layers[1].n = v[5];
    layers[1].z0 = 0;
    layers[1].z1 = v[6];
    layers[1].cos_crit0 = cos_crit(layers[1].n, layers[0].n);
    layers[1].cos_crit1 = cos_crit(layers[1].n, layers[2].n);
    InputStruct in = {{0}};
    in.num_photons = (long)v[1];
    in.Wth = WEIGHT;
    in.dz = 0.1;
    in.dr = 0.1;
    in.nz = 10;
    in.nr = 10;
    in.na = 1;
    in.da = 0.5 * PI / in.na;
    in.num_layers = 1;
    in.layerspecs = layers;
    OutStruct out = {0};
    out.Rd_ra = matrix(in.nr, in.na);
    out.A_rz = matrix(in.nr, in.nz);
    out.Tt_ra = matrix(in.nr, in.na);
    out.Rsp = Rspecular(layers);
    PhotonStruct photon;
    long i_photon = in.num_photons;
    do {
        LaunchPhoton(out.Rsp, layers, &photon);
        do HopDropSpin(&in, &photon, &out);
        while (!photon.dead);
    } while (--i_photon);
    double rd = 0, tt = 0;
    for (int ir = 0; ir < in.nr; ++ir)
        for (int ia = 0; ia < in.na; ++ia) {
            rd += out.Rd_ra[ir][ia];
            tt += out.Tt_ra[ir][ia];
        }
    printf("{\"photons\": %ld, \"Rsp\": %.10g, \"Rd\": %.10g, \"Tt\": %.10g}\n", in.num_photons, out.Rsp,
           rd / in.num_photons, tt / in.num_photons);
    return 0;
}
